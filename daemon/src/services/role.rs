//! The three roles a caller can have, from the least to the most it may do. `access` grants
//! them (to tokens, local users and groups) and `audit` writes them down.

use serde::{Deserialize, Serialize};

/// What a caller may do.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Role {
    /// Reads machines, jobs and events.
    Viewer,
    /// Also submits, pauses, resumes and cancels jobs, and locks machines, on its machines.
    Operator,
    /// Everything, on every machine: breaks locks, reloads the access table.
    Admin,
}

impl std::fmt::Display for Role {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str(match self {
            Role::Viewer => "viewer",
            Role::Operator => "operator",
            Role::Admin => "admin",
        })
    }
}
