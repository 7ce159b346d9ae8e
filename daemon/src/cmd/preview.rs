//! `machlink preview`.

#[derive(clap::Args)]
pub struct PreviewArgs {}

pub fn run(_args: PreviewArgs) -> anyhow::Result<()> {
    anyhow::bail!("`machlink preview` is not built yet")
}
