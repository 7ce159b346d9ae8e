//! A fleet of daemons on NATS JetStream: one job queue and one view of every machine and
//! job, shared by daemons on several hosts (docs/fleet.md).
//!
//! - **Queue**: a work-queue stream per machine group (`MACHLINK_JOBS_<group>`, subjects
//!   `machlink.<group>.jobs.<machine>`) and a durable pull consumer per machine, bound by
//!   the daemon that owns the machine: each job is delivered to exactly one daemon. The
//!   daemon plans it, stores it in its local store, and only then acknowledges it; a daemon
//!   that dies before that gets it again (redelivery after `ack_wait_ms`), and a job it
//!   already stored (found by its fleet id) is acknowledged without being taken twice.
//! - **View**: a key-value bucket (`machlink_fleet`) with `machine.<name>` (owner, group,
//!   status) and `job.<id>` (owner, local job, state, progress), written by the daemon whose
//!   store is the authority for it; a restarted daemon writes every job of its store again.
//! - **Clients**: `machlink submit --fleet nats://…` publishes a job for a machine;
//!   `machlink jobs --fleet nats://…` lists the bucket's jobs.

pub mod client;
pub mod node;

use crate::core::store::JobId;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use std::time::Duration;

/// The key-value bucket of the fleet's view.
pub const BUCKET: &str = "machlink_fleet";
/// The group a daemon joins when its `[fleet]` names none.
pub const DEFAULT_GROUP: &str = "shop";

/// Why the fleet could not be used.
#[derive(Debug, thiserror::Error)]
pub enum FleetError {
    #[error("cannot reach NATS at {url}: {message}")]
    Connect { url: String, message: String },
    #[error("cannot read the NATS credentials {path}: {source}")]
    Credentials {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("JetStream refused {what}: {message}")]
    JetStream { what: String, message: String },
    #[error("no daemon in the fleet has announced machine `{machine}` (known: {known})")]
    UnknownMachine { machine: String, known: String },
    #[error(transparent)]
    Store(#[from] crate::core::store::StoreError),
    #[error(transparent)]
    Sched(#[from] crate::core::scheduler::SchedError),
    #[error("the fleet holds a bad record under `{key}`: {message}")]
    Corrupt { key: String, message: String },
}

impl FleetError {
    pub(crate) fn js(what: impl Into<String>, e: impl std::fmt::Display) -> FleetError {
        FleetError::JetStream {
            what: what.into(),
            message: e.to_string(),
        }
    }
}

/// The `[fleet]` table.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FleetConfig {
    /// The NATS server, `nats://host:4222` (several separated by commas).
    pub url: String,
    /// A NATS credentials file (`.creds`); relative to the config file's folder.
    #[serde(default)]
    pub credentials: Option<PathBuf>,
    /// This daemon's name in the fleet; unique among the daemons.
    pub name: String,
    /// The machines of this daemon whose jobs it takes from the fleet's queue (default:
    /// all its machines).
    #[serde(default)]
    pub machines: Option<Vec<String>>,
    /// The machine group: the daemons of one group share one queue.
    #[serde(default = "default_group")]
    pub group: String,
    /// How long a job handed to a daemon may stay unacknowledged before it is handed out
    /// again (the daemon died before storing it).
    #[serde(default = "default_ack_wait_ms")]
    pub ack_wait_ms: u64,
}

fn default_group() -> String {
    DEFAULT_GROUP.into()
}

fn default_ack_wait_ms() -> u64 {
    30_000
}

/// Whether `s` may be a part of a NATS subject, consumer and key: letters, digits, `-`, `_`.
pub fn is_token(s: &str) -> bool {
    !s.is_empty()
        && s.bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_')
}

impl FleetConfig {
    /// Checks what serde cannot, against the daemon's machine names; the error names the key.
    pub fn check(&self, machines: &[String]) -> Result<(), String> {
        if !self.url.split(',').all(|u| {
            let u = u.trim();
            u.starts_with("nats://") || u.starts_with("tls://")
        }) {
            return Err(format!(
                "key `url`: `{}` must be nats://host:port (or tls://)",
                self.url
            ));
        }
        if !is_token(&self.name) {
            return Err(format!(
                "key `name`: `{}` may hold only letters, digits, `-` and `_`",
                self.name
            ));
        }
        if !is_token(&self.group) {
            return Err(format!(
                "key `group`: `{}` may hold only letters, digits, `-` and `_`",
                self.group
            ));
        }
        if self.ack_wait_ms < 100 {
            return Err("key `ack_wait_ms`: must be 100 or more".into());
        }
        for m in self.owned(machines) {
            if !machines.contains(&m) {
                return Err(format!(
                    "key `machines`: `{m}` is not a machine of this daemon (it has: {})",
                    machines.join(", ")
                ));
            }
            if !is_token(&m) {
                return Err(format!(
                    "key `machines`: a machine in a fleet needs a name of letters, digits, `-` and `_`; `{m}` is not one"
                ));
            }
        }
        Ok(())
    }

    /// The machines this daemon takes fleet jobs for.
    pub fn owned(&self, machines: &[String]) -> Vec<String> {
        self.machines.clone().unwrap_or_else(|| machines.to_vec())
    }

    pub fn ack_wait(&self) -> Duration {
        Duration::from_millis(self.ack_wait_ms)
    }
}

/// The stream of a group's jobs.
pub fn stream_name(group: &str) -> String {
    format!("MACHLINK_JOBS_{group}")
}

/// The subject a job for `machine` is published on.
pub fn job_subject(group: &str, machine: &str) -> String {
    format!("machlink.{group}.jobs.{machine}")
}

/// The durable consumer that hands out `machine`'s jobs.
pub fn consumer_name(machine: &str) -> String {
    format!("machine_{machine}")
}

/// A job as published on the queue.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Submission {
    /// The fleet's id of the job (also the message id that deduplicates a publish).
    pub id: String,
    pub spec: crate::core::intake::JobSpec,
    pub submitted_ms: i64,
}

/// A job as the fleet's view holds it (`job.<id>`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FleetJob {
    pub id: String,
    pub machine: String,
    /// `submitted` (on the queue), `refused` (the machine's checks refused it), or the
    /// state of the job in its daemon's store (`queued`, `running`, … `completed`).
    pub state: String,
    /// The daemon that took it.
    pub daemon: Option<String>,
    /// Its number in that daemon's store.
    pub local_id: Option<JobId>,
    pub acked: usize,
    pub total: usize,
    pub error: Option<String>,
    pub file_name: String,
    pub updated_ms: i64,
}

/// A machine as the fleet's view holds it (`machine.<name>`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FleetMachine {
    pub name: String,
    pub daemon: String,
    pub group: String,
    pub link: String,
    #[serde(flatten)]
    pub status: machlink_protocols::MachineStatus,
    pub job: Option<JobId>,
    pub updated_ms: i64,
}

/// Connects to NATS, with the credentials file if any.
pub async fn connect(
    url: &str,
    credentials: Option<&std::path::Path>,
    name: &str,
) -> Result<async_nats::Client, FleetError> {
    let mut opts = async_nats::ConnectOptions::new().name(name);
    if let Some(c) = credentials {
        opts = opts
            .credentials_file(c)
            .await
            .map_err(|source| FleetError::Credentials {
                path: c.display().to_string(),
                source,
            })?;
    }
    opts.connect(url).await.map_err(|e| FleetError::Connect {
        url: url.to_string(),
        message: e.to_string(),
    })
}

/// The fleet's key-value bucket, created by whoever comes first. The bucket's stream is
/// made here with the key-value layout (`KV_<bucket>`, one value per key, roll-ups, direct
/// reads) rather than by `create_key_value`, which asks the server for account details that
/// nats-server 2.9 (Debian 12's) does not give.
pub async fn bucket(
    js: &async_nats::jetstream::Context,
) -> Result<async_nats::jetstream::kv::Store, FleetError> {
    use async_nats::jetstream::stream;
    if let Ok(kv) = js.get_key_value(BUCKET).await {
        return Ok(kv);
    }
    let made = js
        .get_or_create_stream(stream::Config {
            name: format!("KV_{BUCKET}"),
            description: Some("machlink: machines and jobs of the fleet".into()),
            subjects: vec![format!("$KV.{BUCKET}.>")],
            max_messages_per_subject: 1,
            allow_rollup: true,
            deny_delete: true,
            allow_direct: true,
            discard: stream::DiscardPolicy::New,
            storage: stream::StorageType::File,
            num_replicas: 1,
            ..Default::default()
        })
        .await;
    match js.get_key_value(BUCKET).await {
        Ok(kv) => Ok(kv),
        Err(e) => Err(match made {
            Err(m) => FleetError::js(format!("the bucket {BUCKET}"), m),
            Ok(_) => FleetError::js(format!("the bucket {BUCKET}"), e),
        }),
    }
}

/// The group's job stream, created by whoever comes first.
pub async fn job_stream(
    js: &async_nats::jetstream::Context,
    group: &str,
) -> Result<async_nats::jetstream::stream::Stream, FleetError> {
    use async_nats::jetstream::stream;
    js.get_or_create_stream(stream::Config {
        name: stream_name(group),
        subjects: vec![format!("machlink.{group}.jobs.*")],
        retention: stream::RetentionPolicy::WorkQueue,
        storage: stream::StorageType::File,
        duplicate_window: Duration::from_secs(120),
        ..Default::default()
    })
    .await
    .map_err(|e| FleetError::js(format!("the stream {}", stream_name(group)), e))
}

/// A new fleet job id: milliseconds and randomness, letters and digits only.
pub fn new_id() -> String {
    use std::hash::{BuildHasher, Hasher};
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u128(
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos()),
    );
    h.write_u32(std::process::id());
    format!("{:011x}{:016x}", crate::core::store::now_ms(), h.finish())
}

pub(crate) fn job_key(id: &str) -> String {
    format!("job.{id}")
}

pub(crate) fn machine_key(name: &str) -> String {
    format!("machine.{name}")
}
