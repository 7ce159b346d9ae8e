//! The sewing machine's serial port: the shared pty harness's async view (see `crate::pty`).

pub use crate::pty::PtyPort;
