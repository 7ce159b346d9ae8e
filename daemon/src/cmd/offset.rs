//! `machlink offset`.

#[derive(clap::Args)]
pub struct OffsetArgs {}

pub fn run(_args: OffsetArgs) -> anyhow::Result<()> {
    anyhow::bail!("`machlink offset` is not built yet")
}
