//! `machlink submit`.

#[derive(clap::Args)]
pub struct SubmitArgs {}

pub fn run(_args: SubmitArgs) -> anyhow::Result<()> {
    anyhow::bail!("`machlink submit` is not built yet")
}
