//! How every client command reaches the daemon: its Unix socket (by default), or TCP over TLS
//! with the daemon's CA, or plaintext TCP when spelled out; with a bearer token when needed.

use machlink::faces::client::{Client, Endpoint};
use std::path::PathBuf;

/// How to reach the daemon (every client command takes these).
#[derive(clap::Args, Clone, Debug)]
#[command(group(clap::ArgGroup::new("tcp_mode").args(["ca", "insecure_plaintext"]).multiple(false)))]
pub struct ClientArgs {
    /// The daemon's Unix socket. Default: $MACHLINK_SOCKET, else the `socket` of the
    /// daemon's config (--config), else $XDG_RUNTIME_DIR/machlink.sock, else
    /// /tmp/machlink-$USER/machlink.sock.
    #[arg(long, value_name = "PATH")]
    pub socket: Option<PathBuf>,
    /// The daemon's config, to find its socket. Default: $MACHLINK_CONFIG, else
    /// ./machlink.toml, else ./cell.toml, else /etc/machlink/machlink.toml, whichever
    /// exists.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Reach the daemon on TCP at ADDR instead: over TLS with --ca, or in plaintext with
    /// --insecure-plaintext.
    #[arg(long, value_name = "ADDR", requires = "tcp_mode")]
    pub connect: Option<String>,
    /// The bearer token (from `machlink token new`). Needed on TCP; on the socket only for a
    /// local user the daemon's [access] table does not name.
    #[arg(long, env = "MACHLINK_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// The CA certificate (PEM) that signed the daemon's certificate, for --connect over TLS.
    #[arg(long, value_name = "FILE", requires = "connect")]
    pub ca: Option<PathBuf>,
    /// The name the daemon's certificate carries, when it is not the host of --connect.
    #[arg(long, value_name = "NAME", requires = "ca")]
    pub server_name: Option<String>,
    /// --connect in plaintext, to a daemon started with --insecure-plaintext: the token and
    /// the jobs cross the network readable by anyone on it.
    #[arg(long, requires = "connect")]
    pub insecure_plaintext: bool,
}

impl ClientArgs {
    pub fn client(&self) -> Client {
        Client::new(self.endpoint())
    }

    /// Where the daemon is, as these options say.
    pub fn endpoint(&self) -> Endpoint {
        match (&self.connect, &self.ca) {
            (Some(addr), Some(ca)) => Endpoint::Tls {
                addr: addr.clone(),
                token: self.token.clone(),
                ca: ca.clone(),
                server_name: self.server_name.clone(),
            },
            (Some(addr), None) => Endpoint::Tcp {
                addr: addr.clone(),
                token: self.token.clone(),
            },
            (None, _) => {
                // an unreadable config is named, and the default tried
                let path = machlink::faces::locate::socket(
                    self.socket.as_deref(),
                    self.config.as_deref(),
                    |k| std::env::var(k).ok(),
                )
                .unwrap_or_else(|e| {
                    eprintln!("machlink: warning: {e}");
                    machlink::config::default_socket()
                });
                match &self.token {
                    Some(t) => Endpoint::UnixToken {
                        path,
                        token: t.clone(),
                    },
                    None => Endpoint::Unix(path),
                }
            }
        }
    }
}
