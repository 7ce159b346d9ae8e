//! The subcommands, one module each, and the job options they share (`job`).

pub mod at_machine;
pub mod demo;
pub mod job;
pub mod offset;
pub mod operate;
pub mod plan;
pub mod preview;
pub mod serve;
pub mod submit;
