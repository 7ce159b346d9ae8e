//! `machlink plan`: plan a job offline and write the program; the planning itself is shared
//! with `submit` (see `planning`).

use crate::planning::{self, PlanParams, Post};
use anyhow::Context;
use machlink_protocols::Program;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct PlanCmdArgs {
    /// The shape file (.json geometry).
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
    let shape = planning::read_shape(&a.file)?;
    let tp = planning::plan_toolpath(&shape, &a.params)?;
    let program = planning::post(&tp, a.post)?;
    let text = match &program {
        Program::Gcode(lines) => lines.join("\n") + "\n",
        Program::Modbus(blocks) => blocks.iter().map(|b| format!("{b}\n")).collect(),
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
