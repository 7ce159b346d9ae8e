//! The core: what a job is and what happens to it, with no network and no caller in sight.
//! The store keeps jobs and their journal (SQLite, written before anything is sent); the
//! scheduler runs one queue per machine and streams each job's units through the machine's
//! kind; resume says where a stopped job goes on; intake turns every job into a checked
//! program (planned in a child process by `planner`, checked by `check`); the registry names
//! the machine kinds. Nothing here knows HTTP, tokens or the services around it.

pub mod check;
pub mod intake;
pub mod machine;
pub mod planner;
pub mod registry;
pub mod resume;
pub mod scheduler;
pub mod store;
