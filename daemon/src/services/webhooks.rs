//! Webhooks: each `[[webhook]]` of the config gets a POST of the events it asks for (job
//! states by name, and `message`), as the JSON `machlink events --json` prints. Delivery
//! never holds up the daemon: each webhook has its own queue and sender task, with a
//! timeout per attempt and retries with backoff; a queue that is full drops the event
//! (counted in `machlink_webhook_deliveries_total{result="dropped"}`).
//!
//! Only `http://` URLs: put a relay in front of an HTTPS receiver.

use crate::core::scheduler::Event;
use crate::services::metrics::Metrics;
use http_body_util::{BodyExt, Full};
use hyper::body::Bytes;
use serde::{Deserialize, Serialize};
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::{broadcast, mpsc};
use tokio::task::JoinHandle;

/// The event kinds a webhook may ask for.
pub const KINDS: [&str; 8] = [
    "queued",
    "running",
    "paused",
    "completed",
    "failed",
    "cancelled",
    "interrupted",
    "message",
];

/// How many events may wait for one webhook before new ones are dropped.
pub const QUEUE: usize = 1024;

/// One `[[webhook]]` table.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WebhookConfig {
    /// Where to POST, `http://host:port/path`.
    pub url: String,
    /// The event kinds to send: job states (`completed`, `failed`, …) and `message`.
    pub events: Vec<String>,
    /// How long one attempt may take.
    #[serde(default = "default_timeout_ms")]
    pub timeout_ms: u64,
    /// Attempts after the first failed one.
    #[serde(default = "default_retries")]
    pub retries: u32,
}

fn default_timeout_ms() -> u64 {
    5000
}

fn default_retries() -> u32 {
    3
}

impl WebhookConfig {
    /// Checks what serde cannot; the error names the key.
    pub fn check(&self) -> Result<(), String> {
        let uri: hyper::Uri = self
            .url
            .parse()
            .map_err(|e| format!("key `url`: `{}` is not a URL: {e}", self.url))?;
        match uri.scheme_str() {
            Some("http") => {}
            Some("https") => {
                return Err(format!(
                    "key `url`: `{}`: only http:// webhooks are sent (put a relay in front of an HTTPS receiver)",
                    self.url
                ))
            }
            _ => return Err(format!("key `url`: `{}` must start with http://", self.url)),
        }
        if uri.host().is_none() {
            return Err(format!("key `url`: `{}` names no host", self.url));
        }
        if self.events.is_empty() {
            return Err(format!(
                "key `events`: name at least one of {}",
                KINDS.join(", ")
            ));
        }
        for e in &self.events {
            if !KINDS.contains(&e.as_str()) {
                return Err(format!(
                    "key `events`: unknown event `{e}` (known: {})",
                    KINDS.join(", ")
                ));
            }
        }
        if self.timeout_ms == 0 {
            return Err("key `timeout_ms`: must be above 0".into());
        }
        Ok(())
    }

    fn wants(&self, ev: &Event) -> bool {
        let kind = match ev {
            Event::State { state, .. } => state.as_str(),
            Event::Message { .. } => "message",
            Event::Progress { .. } | Event::Status { .. } => return false,
        };
        self.events.iter().any(|e| e == kind)
    }
}

/// Starts the webhooks' senders and the task that hands them events; the handles stop them.
pub fn start(
    hooks: &[WebhookConfig],
    mut rx: broadcast::Receiver<Event>,
    metrics: Arc<Metrics>,
) -> Vec<JoinHandle<()>> {
    if hooks.is_empty() {
        return Vec::new();
    }
    let mut handles = Vec::new();
    let mut queues = Vec::new();
    for h in hooks {
        let (tx, q) = mpsc::channel::<Arc<Vec<u8>>>(QUEUE);
        handles.push(tokio::spawn(sender(h.clone(), q, metrics.clone())));
        queues.push((h.clone(), tx));
    }
    handles.push(tokio::spawn(async move {
        loop {
            let ev = match rx.recv().await {
                Ok(ev) => ev,
                Err(broadcast::error::RecvError::Lagged(n)) => {
                    tracing::warn!("webhooks missed {n} events (the daemon was too busy)");
                    continue;
                }
                Err(broadcast::error::RecvError::Closed) => return,
            };
            let mut body = None;
            for (h, tx) in &queues {
                if !h.wants(&ev) {
                    continue;
                }
                let b = body
                    .get_or_insert_with(|| Arc::new(serde_json::to_vec(&ev).unwrap_or_default()))
                    .clone();
                if tx.try_send(b).is_err() {
                    metrics.webhook_delivery("dropped");
                    tracing::warn!(url = %h.url, "a webhook's queue is full; an event was dropped");
                }
            }
        }
    }));
    handles
}

/// Sends one webhook's events in order, each with its retries.
async fn sender(hook: WebhookConfig, mut q: mpsc::Receiver<Arc<Vec<u8>>>, metrics: Arc<Metrics>) {
    let timeout = Duration::from_millis(hook.timeout_ms);
    while let Some(body) = q.recv().await {
        let mut attempt = 0;
        loop {
            let r = tokio::time::timeout(timeout, post(&hook.url, &body)).await;
            let err = match r {
                Ok(Ok(())) => {
                    metrics.webhook_delivery("ok");
                    break;
                }
                Ok(Err(e)) => e,
                Err(_) => format!("no answer within {} ms", hook.timeout_ms),
            };
            if attempt >= hook.retries {
                metrics.webhook_delivery("failed");
                tracing::warn!(url = %hook.url, "webhook not delivered after {} attempts: {err}", attempt + 1);
                break;
            }
            attempt += 1;
            let backoff = Duration::from_millis(200u64 << attempt.min(5));
            tokio::time::sleep(backoff).await;
        }
    }
}

/// One POST of `body` as JSON; Ok on a 2xx answer.
async fn post(url: &str, body: &[u8]) -> Result<(), String> {
    let uri: hyper::Uri = url.parse().map_err(|e| format!("{e}"))?;
    let host = uri.host().ok_or("no host")?.to_string();
    let port = uri.port_u16().unwrap_or(80);
    let stream = tokio::net::TcpStream::connect((host.as_str(), port))
        .await
        .map_err(|e| format!("cannot connect to {host}:{port}: {e}"))?;
    let (mut sender, conn) =
        hyper::client::conn::http1::handshake(hyper_util::rt::TokioIo::new(stream))
            .await
            .map_err(|e| e.to_string())?;
    tokio::spawn(async move {
        let _ = conn.await;
    });
    let path = uri
        .path_and_query()
        .map(|p| p.as_str().to_string())
        .unwrap_or_else(|| "/".into());
    let req = hyper::Request::post(path)
        .header(hyper::header::HOST, format!("{host}:{port}"))
        .header(hyper::header::CONTENT_TYPE, "application/json")
        .header(hyper::header::USER_AGENT, "machlink")
        .body(Full::new(Bytes::copy_from_slice(body)))
        .map_err(|e| e.to_string())?;
    let resp = sender.send_request(req).await.map_err(|e| e.to_string())?;
    let status = resp.status();
    let _ = resp.into_body().collect().await;
    if status.is_success() {
        Ok(())
    } else {
        Err(format!("the receiver answered {status}"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::store::JobState;

    #[test]
    fn every_job_state_is_an_event_kind() {
        for s in [
            JobState::Queued,
            JobState::Running,
            JobState::Paused,
            JobState::Completed,
            JobState::Failed,
            JobState::Cancelled,
            JobState::Interrupted,
        ] {
            assert!(KINDS.contains(&s.as_str()), "{s}");
        }
    }

    #[test]
    fn bad_urls_and_kinds_name_the_key() {
        let h = |url: &str, events: &[&str]| WebhookConfig {
            url: url.into(),
            events: events.iter().map(|e| e.to_string()).collect(),
            timeout_ms: 100,
            retries: 0,
        };
        assert!(h("http://127.0.0.1:9/hook", &["failed"]).check().is_ok());
        let e = h("https://x/hook", &["failed"]).check().unwrap_err();
        assert!(
            e.starts_with("key `url`") && e.contains("only http://"),
            "{e}"
        );
        let e = h("http://x/hook", &["finished"]).check().unwrap_err();
        assert!(
            e.starts_with("key `events`") && e.contains("`finished`"),
            "{e}"
        );
    }
}
