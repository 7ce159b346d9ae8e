//! Helpers shared by the daemon crate's tests (each test file uses some of them).
#![allow(dead_code)]
pub mod cli;
pub mod nats;
/// Shared with other crates' tests (testkit/README.md): independent checks of solid meshes,
/// the pyembroidery reader, the sewing seam.
pub use machlink_testkit::{mesh_check, pyembroidery, sewing};
