//! Modbus motion blocks: the register map, the post from the Toolpath IR, the frames both
//! ends share, and the link that streams blocks into a device's ring buffer over Modbus TCP
//! or RTU (docs/modbus.md) in three layers (transport, session, ring), and the two machine
//! kinds.

mod attach;
pub mod frame;
pub mod kind;
pub mod link;
pub mod map;
pub mod post;
mod ring;
pub mod session;
pub mod settings;
pub mod transport;

pub use kind::{ModbusKind, ModbusRtuKind, ModbusTcpKind, RingSettings, RingTransport};
pub use link::{ModbusError, ModbusLink, ModbusSettings, Parity, Transport};
pub use map::{BlockKind, ModbusState, MotionBlock, WordOrder};
pub use post::{post_blocks, ModbusPost, ModbusPostError};
pub use transport::{ByteStream, Endpoint, Framing, ReplyFate, WireCounters};
