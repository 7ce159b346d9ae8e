//! Modbus motion blocks: the register map, the post from the Toolpath IR, the link that
//! streams blocks into a device's ring buffer over Modbus TCP or RTU (docs/modbus.md), and
//! the two machine kinds.

mod attach;
pub mod kind;
pub mod link;
pub mod map;
pub mod post;

pub use kind::{ModbusKind, ModbusRtuKind, ModbusTcpKind, RingSettings, RingTransport};
pub use link::{ModbusError, ModbusLink, ModbusSettings, Parity, Transport};
pub use map::{BlockKind, ModbusState, MotionBlock, WordOrder};
pub use post::{post_blocks, ModbusPost, ModbusPostError};
