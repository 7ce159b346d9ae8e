//! `machlink plan`: plan a job offline and write the program; the planning itself is shared
//! with `submit`.

#[derive(clap::Args)]
pub struct PlanCmdArgs {}

pub fn run(_args: PlanCmdArgs) -> anyhow::Result<()> {
    anyhow::bail!("`machlink plan` is not built yet")
}
