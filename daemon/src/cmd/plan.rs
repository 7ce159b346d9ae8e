//! `machlink plan`: plan a job offline and write the program; the planning itself is shared
//! with `submit` (see `planning`).

use crate::planning::{self, PlanParams, Post};
use anyhow::Context;
use machlink_protocols::Program;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct PlanCmdArgs {
    /// The shape file: .json geometry, .dxf or .svg.
    pub file: PathBuf,
    #[command(flatten)]
    pub params: PlanParams,
    /// The program format to write.
    #[arg(long, value_enum, default_value = "grbl")]
    pub post: Post,
    /// Where to write the program.
    #[arg(short, long)]
    pub output: PathBuf,
}

pub fn run(a: PlanCmdArgs) -> anyhow::Result<()> {
    let shape = planning::read_shape_for(&a.file, &a.params)?;
    let tp = planning::plan_toolpath(&shape, &a.params)?;
    let program = planning::post(&tp, a.post)?;
    let text = match &program {
        Program::Gcode(lines) => (lines.join("\n") + "\n").into_bytes(),
        Program::Stitches(records) => stitch_file(records, a.post, &a.file)?,
        Program::Modbus(blocks) => blocks
            .iter()
            .map(|b| format!("{b}\n"))
            .collect::<String>()
            .into_bytes(),
    };
    std::fs::write(&a.output, text)
        .with_context(|| format!("cannot write {}", a.output.display()))?;
    eprintln!(
        "wrote {} ({} {} units)",
        a.output.display(),
        program.len(),
        program.kind()
    );
    Ok(())
}

/// A stitch program as the embroidery file `post` names (DST unless JEF is asked for).
fn stitch_file(
    records: &[machlink_protocols::sewing::StitchRecord],
    post: Post,
    source: &std::path::Path,
) -> anyhow::Result<Vec<u8>> {
    use machlink_protocols::sewing::{dst, jef};
    let label = source
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    Ok(match post {
        Post::Jef => jef::write(records, &Default::default())?,
        _ => dst::write(records, &label)?,
    })
}
