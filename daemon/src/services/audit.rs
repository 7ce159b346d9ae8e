//! The audit log: one JSON line per state change (and per refused attempt at one), saying who,
//! when, what, from where and with which token. The file is created 0600 and only appended to.

use crate::services::role::Role;
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// One line of the audit log.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Record {
    /// Unix milliseconds.
    pub at_ms: i64,
    /// The caller's name (a token's name or a local user's); none when it was not known.
    pub who: Option<String>,
    pub role: Option<Role>,
    /// The token's name when the caller came with a token.
    pub token: Option<String>,
    /// From where: the socket peer's uid, gid and pid, or the TCP address.
    pub from: String,
    /// The request: method and path (`POST /jobs/7/cancel`), or what the daemon did.
    pub action: String,
    pub machine: Option<String>,
    pub job: Option<i64>,
    /// The HTTP status of the answer.
    pub status: u16,
    /// `done`, `done: <note>`, `failed` or `refused: <why>`.
    pub outcome: String,
}

/// The audit log file.
pub struct Audit {
    path: PathBuf,
    file: Mutex<Option<std::fs::File>>,
}

impl Audit {
    /// Opens (creating 0600, or tightening an existing file to 0600) the log at `path`.
    pub fn open(path: &Path) -> std::io::Result<Audit> {
        let file = crate::services::fsperm::private_append(path)?;
        Ok(Audit {
            path: path.to_path_buf(),
            file: Mutex::new(Some(file)),
        })
    }

    /// A log that writes nowhere (a daemon built by a program that keeps none).
    pub fn none() -> Audit {
        Audit {
            path: PathBuf::new(),
            file: Mutex::new(None),
        }
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Appends one record; a failed write is reported in the daemon's log.
    pub fn write(&self, rec: &Record) {
        let mut f = self.file.lock().unwrap_or_else(|p| p.into_inner());
        let Some(f) = f.as_mut() else { return };
        let mut line = serde_json::to_vec(rec).unwrap_or_default();
        line.push(b'\n');
        if let Err(e) = f.write_all(&line) {
            tracing::error!("cannot write the audit log {}: {e}", self.path.display());
        }
    }

    /// A line about the daemon itself (started, insecure mode, …).
    pub fn daemon(&self, action: &str, outcome: &str) {
        self.write(&Record {
            at_ms: crate::core::store::now_ms(),
            who: Some("daemon".into()),
            role: None,
            token: None,
            from: "daemon".into(),
            action: action.into(),
            machine: None,
            job: None,
            status: 0,
            outcome: outcome.into(),
        });
    }
}

/// Reads an audit log back (for tests and tools).
pub fn read(path: &Path) -> std::io::Result<Vec<Record>> {
    let text = std::fs::read_to_string(path)?;
    Ok(text
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect())
}
