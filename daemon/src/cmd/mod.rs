//! The subcommands, one module each.

pub mod demo;
pub mod offset;
pub mod operate;
pub mod plan;
pub mod preview;
pub mod serve;
pub mod submit;
