//! The access commands: `token new` (a token printed once, and the config lines that grant
//! it), `lock` / `release` (a machine's control lock), `locks`, `whoami`, `reload`.

use super::connect::ClientArgs;
use super::runtime;
use machlink::services::access::{hex, new_token, token_hash, Role};

#[derive(clap::Args)]
pub struct TokenArgs {
    #[command(subcommand)]
    pub command: TokenCommand,
}

#[derive(clap::Subcommand)]
pub enum TokenCommand {
    /// Make a new token: the token goes to stderr, once; the [[access.token]] lines for the
    /// config (with its SHA-256, never the token) go to stdout, e.g. `>> cell.toml`.
    New(TokenNewArgs),
}

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum RoleArg {
    Viewer,
    Operator,
    Admin,
}

#[derive(clap::Args)]
pub struct TokenNewArgs {
    /// What the token may do.
    #[arg(long, value_enum)]
    pub role: RoleArg,
    /// The machines it may steer, comma separated (default: every machine).
    #[arg(long, value_delimiter = ',')]
    pub machines: Option<Vec<String>>,
    /// Its name in the audit log (default: the role and a few random characters).
    #[arg(long)]
    pub name: Option<String>,
    /// Print {"name","token","sha256","toml"} as JSON on stdout instead.
    #[arg(long)]
    pub json: bool,
}

pub fn token(a: TokenArgs) -> anyhow::Result<()> {
    match a.command {
        TokenCommand::New(n) => token_new(n),
    }
}

fn token_new(a: TokenNewArgs) -> anyhow::Result<()> {
    let role = match a.role {
        RoleArg::Viewer => Role::Viewer,
        RoleArg::Operator => Role::Operator,
        RoleArg::Admin => Role::Admin,
    };
    if role == Role::Admin && a.machines.is_some() {
        anyhow::bail!("an admin token holds every machine; leave out --machines");
    }
    let token = new_token().map_err(anyhow::Error::msg)?;
    let sha = hex(&token_hash(&token));
    let name = a.name.unwrap_or_else(|| format!("{role}-{}", &sha[..6]));
    let mut toml = format!(
        "\n[[access.token]]\nname = {}\nrole = \"{role}\"\n",
        quote(&name)
    );
    if let Some(ms) = &a.machines {
        let list: Vec<String> = ms.iter().map(|m| quote(m)).collect();
        toml.push_str(&format!("machines = [{}]\n", list.join(", ")));
    }
    toml.push_str(&format!("sha256 = \"{sha}\"\n"));
    if a.json {
        super::out(&format!(
            "{}\n",
            serde_json::json!({ "name": name, "token": token, "sha256": sha, "toml": toml })
        ))?;
    } else {
        eprintln!("machlink: token `{name}` (shown once, give it to its holder): {token}");
        super::out(&toml)?;
    }
    Ok(())
}

/// A TOML basic string.
fn quote(s: &str) -> String {
    serde_json::to_string(s).unwrap_or_else(|_| "\"\"".into())
}

#[derive(clap::Args)]
pub struct LockArgs {
    /// The machine.
    pub machine: String,
    /// Admins: take the lock over from whoever holds it.
    #[arg(long = "break")]
    pub take_over: bool,
    #[command(flatten)]
    pub client: ClientArgs,
}

#[derive(clap::Args)]
pub struct ReleaseArgs {
    /// The machine.
    pub machine: String,
    #[command(flatten)]
    pub client: ClientArgs,
}

#[derive(clap::Args)]
pub struct PlainArgs {
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub client: ClientArgs,
}

pub fn lock(a: LockArgs) -> anyhow::Result<()> {
    let l = runtime()?.block_on(a.client.client().lock(&a.machine, a.take_over))?;
    match l {
        Some(l) => eprintln!("machine `{}` is locked by `{}`", l.machine, l.holder),
        None => eprintln!("machine `{}` is locked", a.machine),
    }
    Ok(())
}

pub fn release(a: ReleaseArgs) -> anyhow::Result<()> {
    runtime()?.block_on(a.client.client().release(&a.machine))?;
    eprintln!("machine `{}` is free", a.machine);
    Ok(())
}

pub fn locks(a: PlainArgs) -> anyhow::Result<()> {
    let ls = runtime()?.block_on(a.client.client().locks())?;
    if a.json {
        return super::out(&format!("{}\n", serde_json::to_string_pretty(&ls)?));
    }
    let mut text = format!("{:<12} {:<24} {:<9} JOBS\n", "MACHINE", "HOLDER", "HOW");
    for l in ls {
        text.push_str(&format!(
            "{:<12} {:<24} {:<9} {}\n",
            l.machine,
            l.holder,
            if l.explicit { "lock" } else { "submit" },
            l.jobs
                .iter()
                .map(|j| j.to_string())
                .collect::<Vec<_>>()
                .join(",")
        ));
    }
    super::out(&text)
}

pub fn whoami(a: PlainArgs) -> anyhow::Result<()> {
    let w = runtime()?.block_on(a.client.client().whoami())?;
    super::out(&format!("{}\n", serde_json::to_string_pretty(&w)?))
}

pub fn reload(a: PlainArgs) -> anyhow::Result<()> {
    let r = runtime()?.block_on(a.client.client().reload_access())?;
    if a.json {
        return super::out(&format!("{r}\n"));
    }
    eprintln!(
        "reloaded the [access] table of {} ({} tokens)",
        r["reloaded"].as_str().unwrap_or("?"),
        r["tokens"]
    );
    Ok(())
}
