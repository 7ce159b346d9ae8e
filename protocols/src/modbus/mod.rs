//! Modbus motion blocks: the register map, the post from the Toolpath IR, and the link that
//! streams blocks into a device's ring buffer over Modbus TCP or RTU (docs/modbus.md).

pub mod link;
pub mod map;
pub mod post;

pub use link::{ModbusError, ModbusLink, ModbusSettings, Parity, Transport};
pub use map::{BlockKind, MotionBlock, WordOrder};
pub use post::{post, post_blocks, ModbusPostError};
