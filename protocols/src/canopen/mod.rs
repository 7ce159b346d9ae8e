//! CANopen: a master that feeds CiA 402 servo drives a time-parameterised path over a CAN bus
//! (socketcan, an SLCAN adapter, or the in-memory bus of tests). docs/canopen.md is the
//! protocol document.
//!
//! Layers, each usable alone: [`frame`] and the transports ([`bus`], [`memory`], [`slcan`],
//! [`socketcan`]); the wire of each service, shared with the simulated drives ([`sdo`],
//! [`nmt`], [`pdo`], [`od`], [`cia402`]); the [`trajectory`] planner (no I/O); the [`master`]
//! session; and the machine [`kind`].

pub mod adapter;
pub mod bus;
pub mod cia402;
pub mod frame;
pub mod kind;
pub mod master;
pub mod memory;
pub mod nmt;
pub mod od;
pub mod pdo;
pub mod sdo;
pub mod slcan;
pub mod socketcan;
pub mod trajectory;

pub use adapter::BusSpec;
pub use bus::{BusError, CanBus};
pub use frame::CanFrame;
pub use kind::{CanopenKind, CanopenSettings, DriveSettings, MovesPost};
pub use master::{Axis, CanopenLink, CanopenOptions, Pace};

pub use memory::{BusStats, MemoryBus, MemoryPort, MemorySender};
