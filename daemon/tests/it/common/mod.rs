//! Helpers shared by the daemon crate's tests (each test file uses some of them).
#![allow(dead_code)]
pub mod cli;
/// Independent checks of solid meshes (testkit/README.md).
#[path = "../../../../testkit/mesh_check.rs"]
pub mod mesh_check;
pub mod nats;
#[path = "../../../../testkit/pyembroidery.rs"]
pub mod pyembroidery;
#[path = "../../../../testkit/sewing.rs"]
pub mod sewing;
