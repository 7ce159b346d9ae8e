//! The faces the daemon shows: the HTTP API (JSON on a Unix socket, or TCP with a token) with
//! its routes, the bounds on what a request may hold and the streamed G-code upload; and the
//! client the command line speaks it with, which finds the daemon's socket (`locate`). The
//! `machlink` binary's subcommands (`cmd/`) are the last face, on top of the client. Every
//! refusal of the layers below is turned into an HTTP status here, in one place.

pub mod api;
pub mod client;
pub mod dashboard;
pub mod locate;
