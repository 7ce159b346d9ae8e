//! `machlink completions SHELL` and `machlink man`: what the shell and `man` need, made
//! from the same clap definitions as the commands themselves.

use anyhow::Context;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct CompletionsArgs {
    /// The shell: bash, zsh, fish, elvish or powershell.
    pub shell: clap_complete::Shell,
}

#[derive(clap::Args)]
pub struct ManArgs {
    /// Write machlink.1 and one page per subcommand (machlink-serve.1, …) into DIR
    /// instead of printing machlink.1 on stdout.
    #[arg(long, short = 'o', value_name = "DIR")]
    pub out_dir: Option<PathBuf>,
}

/// Prints the completion script for `shell` on stdout.
pub fn completions(a: CompletionsArgs, mut cmd: clap::Command) -> anyhow::Result<()> {
    // made in memory, then written: clap_complete panics on a write error, and a reader
    // that goes away (`| head -3`) is a quiet end, not a panic
    let mut script = Vec::new();
    clap_complete::generate(a.shell, &mut cmd, "machlink", &mut script);
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    out.write_all(&script)
        .and_then(|()| out.flush())
        .context("cannot write the completion script")
}

/// Prints or writes the man pages.
pub fn man(a: ManArgs, cmd: clap::Command) -> anyhow::Result<()> {
    match a.out_dir {
        None => clap_mangen::Man::new(cmd)
            .render(&mut std::io::stdout())
            .context("cannot write the man page"),
        Some(dir) => {
            std::fs::create_dir_all(&dir)
                .with_context(|| format!("cannot create {}", dir.display()))?;
            clap_mangen::generate_to(cmd, &dir)
                .with_context(|| format!("cannot write the man pages into {}", dir.display()))?;
            eprintln!("man pages written to {}", dir.display());
            Ok(())
        }
    }
}
