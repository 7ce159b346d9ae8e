//! The integration tests of the simulators (`machlink-sim`), in one binary: each former test file is a module
//! here (one link of the dependencies instead of one per file). New test modules go here:
//! add the file beside this one and its `mod` line below. Tests that need a process of their
//! own stay apart (docs/testing.md, "One binary per crate").

mod common;

mod canopen_disable;
mod canopen_drive_rules;
mod canopen_kind;
mod canopen_line;
mod canopen_python;
mod canopen_python_rules;
mod canopen_stops;
mod conformance_grbl;
mod conformance_modbus;
mod conformance_sewing;
mod doc_sessions;
mod gcode_post;
mod grbl_link;
mod modbus_rtu_late;
mod modbus_stream;
mod sewing_sim;
mod sewing_upload;
mod trace_cli;
