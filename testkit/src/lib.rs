//! Test helpers that the integration tests of more than one crate need, kept once
//! (testkit/README.md): independent checks of a mesh offset, the `pyembroidery` peer reader
//! of the sewing files, and the sewing job the stop and reattach tests sew.
//!
//! A crate of its own so that it builds optimised in the test profile (the workspace's
//! Cargo.toml): the mesh checks are brute-force geometry over tens of thousands of faces,
//! and at the daemon's opt-level 0 they took 30 s of its tests' time.

pub mod mesh_check;
pub mod pyembroidery;
pub mod sewing;
