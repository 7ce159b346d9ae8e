//! The integration tests of the protocols (`machlink-protocols`), in one binary: each former test file is a module
//! here (one link of the dependencies instead of one per file). New test modules go here:
//! add the file beside this one and its `mod` line below. Tests that need a process of their
//! own stay apart (docs/testing.md, "One binary per crate").

/// Test helpers shared with other crates' tests (testkit/README.md).
use machlink_testkit::pyembroidery;

mod canopen_decoders;
mod canopen_socketcan;
mod fuzz_devices;
mod sewing_files;
mod untrusted_devices;
