//! `machlink dashboard [--open]`: the daemon's web page in a browser. A daemon reached on TCP
//! (`--connect`) serves the page itself: its URL is printed. On the Unix socket, which a
//! browser cannot open, a proxy on a loopback port passes the page's requests to the socket
//! as this user's, but only those that carry the one-time key its URL holds (`#token=…`,
//! which the page keeps as its token); the page's own files need no key, as on the daemon.

use super::connect::ClientArgs;
use super::runtime;
use anyhow::Context;
use axum::body::Body;
use axum::extract::{Request, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use machlink::faces::client::Endpoint;
use machlink::services::access::{route_of, Need};
use std::path::PathBuf;
use std::sync::Arc;

#[derive(clap::Args)]
pub struct DashboardArgs {
    /// Open the page in the desktop's browser (xdg-open) as well as printing its URL.
    #[arg(long)]
    pub open: bool,
    /// The loopback port the proxy to the Unix socket listens on (0: any free one).
    #[arg(long, default_value_t = 0)]
    pub port: u16,
    #[command(flatten)]
    pub client: ClientArgs,
}

pub fn run(a: DashboardArgs) -> anyhow::Result<()> {
    let (path, token) = match a.client.endpoint() {
        Endpoint::Tls { addr, .. } => return show(&format!("https://{addr}/"), a.open),
        Endpoint::Tcp { addr, .. } => return show(&format!("http://{addr}/"), a.open),
        Endpoint::Unix(path) => (path, None),
        Endpoint::UnixToken { path, token } => (path, Some(token)),
    };
    let key = machlink::services::access::new_token().map_err(anyhow::Error::msg)?;
    let proxy = Arc::new(Proxy {
        socket: path.clone(),
        key: key.clone(),
        token,
    });
    runtime()?.block_on(async move {
        // the daemon must be there before a URL is handed out
        super::connect::ClientArgs::client(&a.client)
            .whoami()
            .await
            .with_context(|| format!("no daemon answers on {}", path.display()))?;
        let listener = tokio::net::TcpListener::bind(("127.0.0.1", a.port))
            .await
            .with_context(|| format!("cannot listen on 127.0.0.1:{}", a.port))?;
        let addr = listener.local_addr()?;
        show(&format!("http://{addr}/#token={key}"), a.open)?;
        eprintln!(
            "machlink: serving the dashboard of {} on {addr} until interrupted (Ctrl-C)",
            path.display()
        );
        let app = axum::Router::new().fallback(forward).with_state(proxy);
        axum::serve(listener, app)
            .with_graceful_shutdown(async {
                let _ = tokio::signal::ctrl_c().await;
            })
            .await
            .context("the dashboard proxy stopped")
    })
}

/// Prints the URL (stdout, one line, for scripts) and opens it when asked.
fn show(url: &str, open: bool) -> anyhow::Result<()> {
    super::out(&format!("{url}\n"))?;
    if open {
        match std::process::Command::new("xdg-open")
            .arg(url)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
        {
            Ok(_) => {}
            Err(e) => {
                eprintln!("machlink: cannot open a browser (xdg-open: {e}); open the URL above")
            }
        }
    }
    Ok(())
}

struct Proxy {
    socket: PathBuf,
    key: String,
    /// The token to present on the socket (`--token`), else none: the socket's peer is us.
    token: Option<String>,
}

fn refuse(status: StatusCode, why: &str) -> Response {
    (
        status,
        axum::Json(machlink::faces::api::error::ErrorBody { error: why.into() }),
    )
        .into_response()
}

/// One request of the page, passed to the daemon's socket.
async fn forward(State(p): State<Arc<Proxy>>, mut req: Request) -> Response {
    let page = route_of(req.method(), req.uri().path()).is_some_and(|r| r.need == Need::Page);
    if !page {
        let given = req
            .headers()
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.strip_prefix("Bearer "))
            .unwrap_or("");
        use subtle::ConstantTimeEq;
        if !bool::from(given.as_bytes().ct_eq(p.key.as_bytes())) {
            return refuse(
                StatusCode::UNAUTHORIZED,
                "this proxy needs the key in the URL `machlink dashboard` printed",
            );
        }
    }
    let h = req.headers_mut();
    h.remove(header::AUTHORIZATION);
    if let Some(t) = &p.token {
        match HeaderValue::from_str(&format!("Bearer {t}")) {
            Ok(v) => {
                h.insert(header::AUTHORIZATION, v);
            }
            Err(_) => return refuse(StatusCode::BAD_REQUEST, "the --token is not a header value"),
        }
    }
    let stream = match tokio::net::UnixStream::connect(&p.socket).await {
        Ok(s) => s,
        Err(e) => {
            return refuse(
                StatusCode::BAD_GATEWAY,
                &format!(
                    "the daemon's socket {} does not answer: {e}",
                    p.socket.display()
                ),
            )
        }
    };
    let (mut send, conn) =
        match hyper::client::conn::http1::handshake(hyper_util::rt::TokioIo::new(stream)).await {
            Ok(x) => x,
            Err(e) => {
                return refuse(
                    StatusCode::BAD_GATEWAY,
                    &format!("the daemon's socket: {e}"),
                )
            }
        };
    tokio::spawn(async move {
        let _ = conn.await;
    });
    match send.send_request(req).await {
        Ok(resp) => resp.map(Body::new),
        Err(e) => refuse(
            StatusCode::BAD_GATEWAY,
            &format!("the daemon's socket: {e}"),
        ),
    }
}
