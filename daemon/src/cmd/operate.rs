//! The operator's commands against a running daemon: jobs, machines, watch, pause, resume, cancel.

#[derive(clap::Args)]
pub struct JobsArgs {}
#[derive(clap::Args)]
pub struct MachinesArgs {}
#[derive(clap::Args)]
pub struct JobArgs {}

pub fn jobs(_a: JobsArgs) -> anyhow::Result<()> {
    anyhow::bail!("not built yet")
}
pub fn machines(_a: MachinesArgs) -> anyhow::Result<()> {
    anyhow::bail!("not built yet")
}
pub fn watch(_a: JobArgs) -> anyhow::Result<()> {
    anyhow::bail!("not built yet")
}
pub fn pause(_a: JobArgs) -> anyhow::Result<()> {
    anyhow::bail!("not built yet")
}
pub fn resume(_a: JobArgs) -> anyhow::Result<()> {
    anyhow::bail!("not built yet")
}
pub fn cancel(_a: JobArgs) -> anyhow::Result<()> {
    anyhow::bail!("not built yet")
}
