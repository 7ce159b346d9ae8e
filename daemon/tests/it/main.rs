//! The integration tests of the daemon (`machlink`), in one binary: each former test file is a module
//! here (one link of the dependencies instead of one per file). New test modules go here:
//! add the file beside this one and its `mod` line below. Tests that need a process of their
//! own stay apart (docs/testing.md, "One binary per crate").

mod common;
mod proc;

mod adaptive_cli;
mod cli;
mod cli_3d;
mod cli_access;
mod cli_stl_files;
mod crash;
mod dashboard_cli;
mod fleet;
mod fuzz_inputs;
mod hatch_cli;
mod intake;
mod kind_recipe;
mod metrics;
mod nothing_moves_without_the_operator;
mod offset_cmd;
mod operator_cli;
mod other_cam_cli;
mod plan_preview_cli;
mod posts_cli;
mod screens_cli;
mod service;
mod shop_jobs_cli;
mod silent_devices;
mod simulate_cli;
mod toolpaths_cli;
