//! The API's client (hyper 1 over a Unix socket or TCP), used by the operator's commands.

use crate::api::ErrorBody;
use crate::intake::JobSpec;
use crate::scheduler::{Event, MachineInfo};
use crate::store::{JobId, JobRecord};
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
    /// host:port, with the bearer token the daemon was started with.
    Tcp {
        addr: String,
        token: Option<String>,
    },
}

impl std::fmt::Display for Endpoint {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        match self {
            Endpoint::Unix(p) => write!(f, "{}", p.display()),
            Endpoint::Tcp { addr, .. } => write!(f, "{addr}"),
        }
    }
}

/// Why a request to the daemon failed.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    #[error("cannot reach the daemon at {0}: is `machlink serve` running?")]
    Unreachable(String),
    /// The daemon's own sentence.
    #[error("{0}")]
    Refused(String),
    #[error("the daemon's answer made no sense: {0}")]
    Protocol(String),
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
        let unreachable = || ClientError::Unreachable(self.endpoint.to_string());
        let mut req = Request::builder()
            .method(method)
            .uri(path)
            .header(hyper::header::HOST, "machlink");
        if body.is_some() {
            req = req.header(hyper::header::CONTENT_TYPE, "application/json");
        }
        let sender = match &self.endpoint {
            Endpoint::Unix(p) => {
                let io = tokio::net::UnixStream::connect(p)
                    .await
                    .map_err(|_| unreachable())?;
                handshake(io).await?
            }
            Endpoint::Tcp { addr, token } => {
                if let Some(t) = token {
                    req = req.header(hyper::header::AUTHORIZATION, format!("Bearer {t}"));
                }
                let io = tokio::net::TcpStream::connect(addr)
                    .await
                    .map_err(|_| unreachable())?;
                handshake(io).await?
            }
        };
        let mut sender = sender;
        let req = req
            .body(Full::new(Bytes::from(body.unwrap_or_default())))
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
        let bytes = body
            .collect()
            .await
            .map_err(|e| ClientError::Protocol(e.to_string()))?
            .to_bytes();
        if !status.is_success() {
            return Err(refusal(status, &bytes));
        }
        serde_json::from_slice(&bytes).map_err(|e| ClientError::Protocol(e.to_string()))
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
        let body = serde_json::to_vec(&crate::api::ResumeRequest {
            from_line: Some(line),
        })
        .map_err(|e| ClientError::Protocol(e.to_string()))?;
        self.call(Method::POST, &format!("/jobs/{id}/resume"), Some(body))
            .await
    }

    /// What a resume of the job would do (from `from_line`, 1-based, when given).
    pub async fn resume_preview(
        &self,
        id: JobId,
        from_line: Option<usize>,
    ) -> Result<crate::resume::ResumePreview, ClientError> {
        let q = from_line.map_or(String::new(), |l| format!("?from_line={l}"));
        self.call(Method::GET, &format!("/jobs/{id}/resume{q}"), None)
            .await
    }

    /// Changes a running job's overrides; the answer holds those now in force.
    pub async fn override_job(
        &self,
        id: JobId,
        patch: &crate::scheduler::OverridePatch,
    ) -> Result<crate::api::OverrideAnswer, ClientError> {
        let body = serde_json::to_vec(patch).map_err(|e| ClientError::Protocol(e.to_string()))?;
        self.call(Method::POST, &format!("/jobs/{id}/override"), Some(body))
            .await
    }

    /// An operator's operation on a machine between jobs; the answer is what it said.
    pub async fn operate(
        &self,
        machine: &str,
        op: &machlink_protocols::Operation,
    ) -> Result<crate::api::OperateAnswer, ClientError> {
        use machlink_protocols::Operation;
        let (name, body) = match op {
            Operation::Unlock => ("unlock", None),
            Operation::Home => ("home", None),
            Operation::Jog { x, y, z, feed } => (
                "jog",
                Some(
                    serde_json::to_vec(&serde_json::json!({"x": x, "y": y, "z": z, "feed": feed}))
                        .map_err(|e| ClientError::Protocol(e.to_string()))?,
                ),
            ),
        };
        self.call(Method::POST, &format!("/machines/{machine}/{name}"), body)
            .await
    }

    /// The job's events, from its current state until it ends.
    pub async fn events(&self, id: JobId) -> Result<EventStream, ClientError> {
        let (status, mut body) = self
            .send(Method::GET, &format!("/jobs/{id}/events"), None)
            .await?;
        if !status.is_success() {
            let bytes = (&mut body)
                .collect()
                .await
                .map_err(|e| ClientError::Protocol(e.to_string()))?
                .to_bytes();
            return Err(refusal(status, &bytes));
        }
        Ok(EventStream {
            body,
            buf: Vec::new(),
        })
    }
}

async fn handshake<S>(
    io: S,
) -> Result<hyper::client::conn::http1::SendRequest<Full<Bytes>>, ClientError>
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
