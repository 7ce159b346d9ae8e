//! The subcommands, one module each, and the job options they share (`job`).

pub mod check_config;
pub mod completions;
pub mod demo;
pub mod events;
pub mod fleet;
pub mod job;
pub mod offset;
pub mod operate;
pub mod plan;
pub mod preview;
pub mod serve;
pub mod submit;
