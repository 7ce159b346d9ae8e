//! The API's client (hyper 1 over a Unix socket or TCP), used by the operator's commands.

use crate::core::intake::JobSpec;
use crate::core::scheduler::{Event, MachineInfo};
use crate::core::store::{JobId, JobRecord};
use crate::faces::api::error::ErrorBody;
use http_body_util::{BodyExt, Full};
use hyper::body::{Bytes, Incoming};
use hyper::{Method, Request, StatusCode};
use hyper_util::rt::TokioIo;
use serde::de::DeserializeOwned;
use std::path::PathBuf;

/// Where the daemon listens.
#[derive(Clone, Debug)]
pub enum Endpoint {
    Unix(PathBuf),
    /// host:port in plaintext (a daemon started with --insecure-plaintext), with a token.
    Tcp {
        addr: String,
        token: Option<String>,
    },
    /// host:port over TLS, trusting the CA certificates in `ca` (PEM), with a token.
    Tls {
        addr: String,
        token: Option<String>,
        ca: PathBuf,
        /// The name the daemon's certificate must carry (default: the host of `addr`).
        server_name: Option<String>,
    },
    /// A Unix socket, with a token (for a local user the `[access]` table does not name).
    UnixToken {
        path: PathBuf,
        token: String,
    },
}

impl std::fmt::Display for Endpoint {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        match self {
            Endpoint::Unix(p) | Endpoint::UnixToken { path: p, .. } => write!(f, "{}", p.display()),
            Endpoint::Tcp { addr, .. } | Endpoint::Tls { addr, .. } => write!(f, "{addr}"),
        }
    }
}

/// Why a request to the daemon failed.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    #[error("cannot reach the daemon at {0}: is `machlink serve` running?")]
    Unreachable(String),
    /// The socket is there but this user may not open it (its mode, its folder's, a group
    /// the user is not in).
    #[error("permission denied: you may not open the daemon's socket {0} (ask for a role, docs/security.md)")]
    PermissionDenied(String),
    /// The daemon's own sentence.
    #[error("{0}")]
    Refused(String),
    #[error("the daemon's answer made no sense: {0}")]
    Protocol(String),
    /// The TLS handshake failed (a certificate the CA does not vouch for, a plaintext daemon).
    #[error("no TLS connection to the daemon at {addr}: {why}")]
    Tls { addr: String, why: String },
    /// The client's own files (a CA file, a file to send).
    #[error("{0}")]
    Local(String),
}

/// A client of one daemon.
#[derive(Clone, Debug)]
pub struct Client {
    pub endpoint: Endpoint,
}

impl Client {
    pub fn new(endpoint: Endpoint) -> Client {
        Client { endpoint }
    }

    async fn send(
        &self,
        method: Method,
        path: &str,
        body: Option<Vec<u8>>,
    ) -> Result<(StatusCode, Incoming), ClientError> {
        let has_body = body.is_some();
        let body = Full::new(Bytes::from(body.unwrap_or_default()))
            .map_err(|never| match never {})
            .boxed_unsync();
        self.send_body(method, path, body, has_body.then_some("application/json"))
            .await
    }

    async fn send_body(
        &self,
        method: Method,
        path: &str,
        body: Body,
        content_type: Option<&str>,
    ) -> Result<(StatusCode, Incoming), ClientError> {
        let unreachable = || ClientError::Unreachable(self.endpoint.to_string());
        let mut req = Request::builder()
            .method(method)
            .uri(path)
            .header(hyper::header::HOST, "machlink");
        if let Some(ct) = content_type {
            req = req.header(hyper::header::CONTENT_TYPE, ct);
        }
        let token = match &self.endpoint {
            Endpoint::Tcp { token, .. } | Endpoint::Tls { token, .. } => token.clone(),
            Endpoint::UnixToken { token, .. } => Some(token.clone()),
            Endpoint::Unix(_) => None,
        };
        if let Some(t) = token {
            req = req.header(hyper::header::AUTHORIZATION, format!("Bearer {t}"));
        }
        let mut sender = match &self.endpoint {
            Endpoint::Unix(p) | Endpoint::UnixToken { path: p, .. } => {
                let io = tokio::net::UnixStream::connect(p).await.map_err(|e| {
                    if e.kind() == std::io::ErrorKind::PermissionDenied {
                        ClientError::PermissionDenied(p.display().to_string())
                    } else {
                        unreachable()
                    }
                })?;
                handshake(io).await?
            }
            Endpoint::Tcp { addr, .. } => {
                let io = tokio::net::TcpStream::connect(addr)
                    .await
                    .map_err(|_| unreachable())?;
                handshake(io).await?
            }
            Endpoint::Tls {
                addr,
                ca,
                server_name,
                ..
            } => {
                let cfg = crate::services::tls::client_config(ca).map_err(ClientError::Local)?;
                // a daemon that is not there is unreachable; one that fails the handshake
                // is refused
                tokio::net::TcpStream::connect(addr)
                    .await
                    .map_err(|_| unreachable())?;
                let io = crate::services::tls::connect(addr, server_name.as_deref(), cfg)
                    .await
                    .map_err(|e| ClientError::Tls {
                        addr: addr.clone(),
                        why: e.to_string(),
                    })?;
                handshake(io).await?
            }
        };
        let req = req
            .body(body)
            .map_err(|e| ClientError::Protocol(e.to_string()))?;
        let resp = sender
            .send_request(req)
            .await
            .map_err(|e| ClientError::Protocol(format!("the request failed: {e}")))?;
        Ok((resp.status(), resp.into_body()))
    }

    async fn call<T: DeserializeOwned>(
        &self,
        method: Method,
        path: &str,
        body: Option<Vec<u8>>,
    ) -> Result<T, ClientError> {
        let (status, body) = self.send(method, path, body).await?;
        answer(status, &whole(body).await?)
    }

    pub async fn machines(&self) -> Result<Vec<MachineInfo>, ClientError> {
        self.call(Method::GET, "/machines", None).await
    }

    pub async fn jobs(&self) -> Result<Vec<JobRecord>, ClientError> {
        self.call(Method::GET, "/jobs", None).await
    }

    pub async fn job(&self, id: JobId) -> Result<JobRecord, ClientError> {
        self.call(Method::GET, &format!("/jobs/{id}"), None).await
    }

    pub async fn submit(&self, req: &JobSpec) -> Result<JobRecord, ClientError> {
        let body = serde_json::to_vec(req).map_err(|e| ClientError::Protocol(e.to_string()))?;
        self.call(Method::POST, "/jobs", Some(body)).await
    }

    /// `action` is pause, resume or cancel.
    pub async fn act(&self, id: JobId, action: &str) -> Result<JobRecord, ClientError> {
        self.call(Method::POST, &format!("/jobs/{id}/{action}"), None)
            .await
    }

    /// Restarts a stopped job from program line `line` (1-based).
    pub async fn resume_from_line(&self, id: JobId, line: usize) -> Result<JobRecord, ClientError> {
        let body = serde_json::to_vec(&crate::faces::api::jobs::ResumeRequest {
            from_line: Some(line),
        })
        .map_err(|e| ClientError::Protocol(e.to_string()))?;
        self.call(Method::POST, &format!("/jobs/{id}/resume"), Some(body))
            .await
    }

    /// Sends a G-code file to machine `machine` as it is, streamed from disk (the daemon
    /// checks each line as it arrives and stores the program without holding the file).
    pub async fn submit_gcode_file(
        &self,
        machine: &str,
        path: &std::path::Path,
    ) -> Result<JobRecord, ClientError> {
        let file = tokio::fs::File::open(path)
            .await
            .map_err(|e| ClientError::Local(format!("cannot read {}: {e}", path.display())))?;
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| path.display().to_string());
        let stream = tokio_util_free_reader(file);
        let body = http_body_util::StreamBody::new(stream).boxed_unsync();
        let uri = format!(
            "/machines/{}/gcode?file_name={}",
            encode(machine),
            encode(&name)
        );
        let (status, body) = self
            .send_body(Method::POST, &uri, body, Some("text/plain"))
            .await?;
        answer(status, &whole(body).await?)
    }

    /// Takes machine `machine`'s control lock; `take_over` (admins) breaks someone else's.
    pub async fn lock(
        &self,
        machine: &str,
        take_over: bool,
    ) -> Result<Option<crate::services::access::LockInfo>, ClientError> {
        let body = serde_json::to_vec(&crate::faces::api::access::LockRequest { take_over })
            .map_err(|e| ClientError::Protocol(e.to_string()))?;
        self.call(
            Method::POST,
            &format!("/machines/{}/lock", encode(machine)),
            Some(body),
        )
        .await
    }

    /// Releases machine `machine`'s control lock (its holder, or an admin breaking it).
    pub async fn release(&self, machine: &str) -> Result<serde_json::Value, ClientError> {
        self.call(
            Method::POST,
            &format!("/machines/{}/release", encode(machine)),
            None,
        )
        .await
    }

    /// The locks held now.
    pub async fn locks(&self) -> Result<Vec<crate::services::access::LockInfo>, ClientError> {
        self.call(Method::GET, "/locks", None).await
    }

    /// Who the daemon takes this client for.
    pub async fn whoami(&self) -> Result<serde_json::Value, ClientError> {
        self.call(Method::GET, "/whoami", None).await
    }

    /// Has the daemon reread its config's `[access]` table.
    pub async fn reload_access(&self) -> Result<serde_json::Value, ClientError> {
        self.call(Method::POST, "/access/reload", None).await
    }

    /// Any request, for tools and tests: the status and the body.
    pub async fn raw(
        &self,
        method: Method,
        path: &str,
        body: Option<Vec<u8>>,
    ) -> Result<(StatusCode, Bytes), ClientError> {
        let (status, body) = self.send(method, path, body).await?;
        Ok((status, whole(body).await?))
    }

    /// What a resume of the job would do (from `from_line`, 1-based, when given).
    pub async fn resume_preview(
        &self,
        id: JobId,
        from_line: Option<usize>,
    ) -> Result<crate::core::resume::ResumePreview, ClientError> {
        let q = from_line.map_or(String::new(), |l| format!("?from_line={l}"));
        self.call(Method::GET, &format!("/jobs/{id}/resume{q}"), None)
            .await
    }

    /// Changes a running job's overrides; the answer holds those now in force.
    pub async fn override_job(
        &self,
        id: JobId,
        patch: &crate::core::scheduler::OverridePatch,
    ) -> Result<crate::faces::api::jobs::OverrideAnswer, ClientError> {
        let body = serde_json::to_vec(patch).map_err(|e| ClientError::Protocol(e.to_string()))?;
        self.call(Method::POST, &format!("/jobs/{id}/override"), Some(body))
            .await
    }

    /// An operator's operation on a machine between jobs; the answer is what it said.
    pub async fn operate(
        &self,
        machine: &str,
        op: &machlink_protocols::Operation,
    ) -> Result<crate::faces::api::jobs::OperateAnswer, ClientError> {
        self.operate_confirmed(machine, op, false).await
    }

    /// Like [`Client::operate`], with the operator's yes to what a jog warns about (an XY
    /// jog while the tool stands below the stock top).
    pub async fn operate_confirmed(
        &self,
        machine: &str,
        op: &machlink_protocols::Operation,
        yes: bool,
    ) -> Result<crate::faces::api::jobs::OperateAnswer, ClientError> {
        use machlink_protocols::Operation;
        let (name, body) = match op {
            Operation::Unlock => ("unlock", None),
            Operation::Home => ("home", None),
            Operation::Jog { x, y, z, feed } => (
                "jog",
                Some(
                    serde_json::to_vec(
                        &serde_json::json!({"x": x, "y": y, "z": z, "feed": feed, "yes": yes}),
                    )
                    .map_err(|e| ClientError::Protocol(e.to_string()))?,
                ),
            ),
        };
        self.call(
            Method::POST,
            &format!("/machines/{}/{name}", encode(machine)),
            body,
        )
        .await
    }

    /// A text resource such as `GET /metrics`.
    pub async fn text(&self, path: &str) -> Result<String, ClientError> {
        let (status, body) = self.send(Method::GET, path, None).await?;
        let bytes = whole(body).await?;
        if !status.is_success() {
            return Err(refusal(status, &bytes));
        }
        Ok(String::from_utf8_lossy(&bytes).into_owned())
    }

    /// Every job's events from now on (`GET /events`), or only `machine`'s; never ends
    /// while the daemon runs.
    pub async fn follow(&self, machine: Option<&str>) -> Result<EventStream, ClientError> {
        let path = match machine {
            Some(m) => format!("/events?machine={}", encode(m)),
            None => "/events".to_string(),
        };
        self.event_stream(&path).await
    }

    /// The job's events, from its current state until it ends.
    pub async fn events(&self, id: JobId) -> Result<EventStream, ClientError> {
        self.event_stream(&format!("/jobs/{id}/events")).await
    }

    /// A stream of JSON-line events at `path` (a refusal read whole as the daemon's error).
    async fn event_stream(&self, path: &str) -> Result<EventStream, ClientError> {
        let (status, body) = self.send(Method::GET, path, None).await?;
        if !status.is_success() {
            return Err(refusal(status, &whole(body).await?));
        }
        Ok(EventStream {
            body,
            buf: Vec::new(),
        })
    }
}

/// A request body: bytes in memory, or a file streamed from disk.
type Body = http_body_util::combinators::UnsyncBoxBody<Bytes, std::io::Error>;

async fn handshake<S>(io: S) -> Result<hyper::client::conn::http1::SendRequest<Body>, ClientError>
where
    S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin + Send + 'static,
{
    let (sender, conn) = hyper::client::conn::http1::handshake(TokioIo::new(io))
        .await
        .map_err(|e| ClientError::Protocol(format!("the HTTP handshake failed: {e}")))?;
    tokio::spawn(async move {
        let _ = conn.await;
    });
    Ok(sender)
}

/// The whole body of a reply.
async fn whole(body: Incoming) -> Result<Bytes, ClientError> {
    Ok(body
        .collect()
        .await
        .map_err(|e| ClientError::Protocol(e.to_string()))?
        .to_bytes())
}

/// A reply read as JSON, or the daemon's refusal when its status is not a success.
fn answer<T: DeserializeOwned>(status: StatusCode, bytes: &[u8]) -> Result<T, ClientError> {
    if !status.is_success() {
        return Err(refusal(status, bytes));
    }
    serde_json::from_slice(bytes).map_err(|e| ClientError::Protocol(e.to_string()))
}

fn refusal(status: StatusCode, bytes: &[u8]) -> ClientError {
    match serde_json::from_slice::<ErrorBody>(bytes) {
        Ok(e) => ClientError::Refused(e.error),
        Err(_) => ClientError::Protocol(format!(
            "status {status}: {}",
            String::from_utf8_lossy(bytes)
        )),
    }
}

/// Events as they come, one JSON line each.
pub struct EventStream {
    body: Incoming,
    buf: Vec<u8>,
}

impl EventStream {
    /// The next event; None when the daemon ended the stream (the job is over).
    pub async fn next(&mut self) -> Result<Option<Event>, ClientError> {
        loop {
            if let Some(nl) = self.buf.iter().position(|&b| b == b'\n') {
                let line: Vec<u8> = self.buf.drain(..=nl).collect();
                return serde_json::from_slice(&line)
                    .map(Some)
                    .map_err(|e| ClientError::Protocol(format!("a bad event: {e}")));
            }
            match self.body.frame().await {
                None => return Ok(None),
                Some(Err(e)) => return Err(ClientError::Protocol(e.to_string())),
                Some(Ok(frame)) => {
                    if let Ok(data) = frame.into_data() {
                        self.buf.extend_from_slice(&data);
                    }
                }
            }
        }
    }
}

/// A path segment or query value, percent-encoded.
fn encode(s: &str) -> String {
    let mut out = String::new();
    for b in s.bytes() {
        if b.is_ascii_alphanumeric() || matches!(b, b'-' | b'_' | b'.' | b'~') {
            out.push(b as char);
        } else {
            out.push_str(&format!("%{b:02X}"));
        }
    }
    out
}

/// A file as a stream of body frames, 256 KiB at a time.
fn tokio_util_free_reader(
    file: tokio::fs::File,
) -> impl futures::Stream<Item = Result<hyper::body::Frame<Bytes>, std::io::Error>> + Send {
    futures::stream::unfold(Some(file), |file| async move {
        use tokio::io::AsyncReadExt;
        let mut file = file?;
        let mut buf = vec![0u8; 256 << 10];
        match file.read(&mut buf).await {
            Ok(0) => None,
            Ok(n) => {
                buf.truncate(n);
                Some((Ok(hyper::body::Frame::data(Bytes::from(buf))), Some(file)))
            }
            Err(e) => Some((Err(e), None)),
        }
    })
}
