//! G-code posts: GRBL, LinuxCNC and a generic dialect, from the Toolpath IR to program lines.

use crate::program::Program;
use offset_core::Toolpath;
use serde::{Deserialize, Serialize};

/// Which controller the G-code is for.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Dialect {
    #[default]
    Grbl,
    Linuxcnc,
    Generic,
}

/// Settings of one post run.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct GcodeOptions {
    pub dialect: Dialect,
}

/// Why a tool path could not be posted.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PostError {
    #[error("the G-code post is not built yet")]
    NotImplemented,
}

/// Turns a tool path into G-code lines for the dialect.
pub fn post(_tp: &Toolpath, _opts: &GcodeOptions) -> Result<Program, PostError> {
    Err(PostError::NotImplemented)
}
