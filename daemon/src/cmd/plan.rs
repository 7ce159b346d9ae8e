//! `machlink plan`: plan a job offline and write the program as the post's file. The
//! planning is the intake's (`machlink::intake::plan`), the same `submit` uses.

use super::job::{print_warnings, JobArgs};
use anyhow::Context;
use machlink::intake::{self, Target};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct PlanCmdArgs {
    /// The shape file: .json geometry, .dxf or .svg.
    pub file: PathBuf,
    #[command(flatten)]
    pub job: JobArgs,
    /// The program format to write: grbl, linuxcnc, generic, modbus, dst, jef (see
    /// `docs/toolpaths.md`).
    #[arg(long, default_value = "grbl")]
    pub post: String,
    /// Where to write the program.
    #[arg(short, long)]
    pub output: PathBuf,
}

pub fn run(a: PlanCmdArgs) -> anyhow::Result<()> {
    let registry = machlink::registry::standard();
    let post = registry.post(&a.post).with_context(|| {
        format!(
            "there is no post `{}` (known: {})",
            a.post,
            registry.post_names().join(", ")
        )
    })?;
    let spec = a.job.spec(&a.file, None, Some(a.post.clone()))?;
    let planned = intake::plan(&spec, Target::Post(post))?;
    print_warnings(&planned.warnings);
    let bytes = post.file(&planned.program, &label(&a.file))?;
    std::fs::write(&a.output, bytes)
        .with_context(|| format!("cannot write {}", a.output.display()))?;
    eprintln!(
        "wrote {} ({} {} units)",
        a.output.display(),
        planned.program.len(),
        post.name()
    );
    Ok(())
}

/// The job's label in a file header (a DST's): the input file's stem.
pub fn label(path: &std::path::Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}
