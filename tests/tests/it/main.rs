//! The integration tests of the end-to-end tests (`machlink-tests`), in one binary: each former test file is a module
//! here (one link of the dependencies instead of one per file). New test modules go here:
//! add the file beside this one and its `mod` line below. Tests that need a process of their
//! own stay apart (docs/testing.md, "One binary per crate").

mod common;

mod access;
mod api;
mod at_machine;
mod canopen_e2e;
mod dashboard_browser;
mod doc_examples;
mod gcode_checks;
mod hardening;
mod modbus_e2e;
mod modbus_pymodbus;
mod module_graph;
mod operate;
mod preview_png;
mod reattach;
mod resume_from_line;
mod sewing_e2e;
mod streaming;
mod tls;
mod toolpaths_grbl;
