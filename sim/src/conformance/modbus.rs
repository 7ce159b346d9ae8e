//! The motion-block device's state table (docs/modbus.md): every request in every state, with the reply and the next state a device must give, and a driver that checks one cell on a device over Modbus.

use machlink_protocols::modbus::frame::{exception, Request};
use machlink_protocols::modbus::map::{
    reg, BlockKind, Command, Layout, ModbusState, MotionBlock, Status, BLOCK_REGISTERS,
    STATUS_REGISTERS,
};
use machlink_protocols::modbus::{ModbusError, ModbusLink};
use std::time::Duration;
use ModbusState::{Fault, Hold, Idle, Running};

/// The states of the table's columns, in order.
pub const STATES: [ModbusState; 4] = [Idle, Running, Hold, Fault];

/// The requests of the table's rows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ask {
    Start,
    Hold,
    Resume,
    Stop,
    ClearFault,
    Sync,
    NoCommand,
    UnknownCommand,
    SeqForward,
    SeqPastRing,
    SeqBack,
    SeqHalf,
    ReadOnly,
    Reserved,
    FreeSlot,
    CommittedSlot,
    ReadHeader,
    ReadPastMap,
    ReadTooMany,
    UnknownFunction,
}

/// Every row, in the document's order.
pub const ASKS: [Ask; 20] = [
    Ask::Start,
    Ask::Hold,
    Ask::Resume,
    Ask::Stop,
    Ask::ClearFault,
    Ask::Sync,
    Ask::NoCommand,
    Ask::UnknownCommand,
    Ask::SeqForward,
    Ask::SeqPastRing,
    Ask::SeqBack,
    Ask::SeqHalf,
    Ask::ReadOnly,
    Ask::Reserved,
    Ask::FreeSlot,
    Ask::CommittedSlot,
    Ask::ReadHeader,
    Ask::ReadPastMap,
    Ask::ReadTooMany,
    Ask::UnknownFunction,
];

impl Ask {
    /// The row's heading in the document.
    pub fn text(self) -> &'static str {
        match self {
            Ask::Start => "command 1 (start)",
            Ask::Hold => "command 2 (hold)",
            Ask::Resume => "command 3 (resume)",
            Ask::Stop => "command 4 (stop)",
            Ask::ClearFault => "command 5 (clear fault)",
            Ask::Sync => "command 6 (sync)",
            Ask::NoCommand => "command 0 (none)",
            Ask::UnknownCommand => "command 7 or above",
            Ask::SeqForward => "write sequence := w, write ≤ w ≤ consumed + N",
            Ask::SeqPastRing => "write sequence := w > consumed + N",
            Ask::SeqBack => "write sequence := w < write",
            Ask::SeqHalf => "one register of the write sequence alone",
            Ask::ReadOnly => "write to registers 0–4 or 8–15",
            Ask::Reserved => "write to registers 16–31",
            Ask::FreeSlot => "write to a slot holding no committed block",
            Ask::CommittedSlot => "write to the slot of a committed block not yet finished",
            Ask::ReadHeader => "FC3 read inside the map (1–125 registers)",
            Ask::ReadPastMap => "FC3 read reaching past the map",
            Ask::ReadTooMany => "FC3 read of 0 or more than 125 registers",
            Ask::UnknownFunction => "any function but 3, 6, 16, 23",
        }
    }
}

/// What the device does on one request in one state.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Cell {
    /// `None`: a normal reply; `Some(code)`: this exception, and nothing changes.
    pub exception: Option<u8>,
    /// The state after it; `None`: the state stays.
    pub next: Option<ModbusState>,
    pub effect: Effect,
}

/// What a request does beyond the state word.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Effect {
    None,
    /// write sequence := consumed sequence (unexecuted blocks dropped).
    WriteToConsumed,
    /// consumed sequence := write sequence.
    ConsumedToWrite,
    /// fault code := 0 and write sequence := consumed sequence.
    FaultCleared,
    /// The write sequence holds what was written.
    SeqWritten,
}

fn ok(next: Option<ModbusState>, effect: Effect) -> Cell {
    Cell {
        exception: None,
        next,
        effect,
    }
}

fn refused(code: u8) -> Cell {
    Cell {
        exception: Some(code),
        next: None,
        effect: Effect::None,
    }
}

/// The table: what a device does on `ask` in `state`.
pub fn cell(ask: Ask, state: ModbusState) -> Cell {
    use Effect as E;
    match (ask, state) {
        (Ask::Start, Idle) => ok(Some(Running), E::None),
        (Ask::Start, Fault) => refused(exception::DEVICE_FAILURE),
        (Ask::Hold, Running) => ok(Some(Hold), E::None),
        (Ask::Resume, Hold) => ok(Some(Running), E::None),
        (Ask::Stop, Fault) => ok(None, E::None),
        (Ask::Stop, _) => ok(Some(Idle), E::WriteToConsumed),
        (Ask::ClearFault, Fault) => ok(Some(Idle), E::FaultCleared),
        (Ask::Sync, Idle) => ok(None, E::ConsumedToWrite),
        (Ask::Sync, _) => refused(exception::ILLEGAL_VALUE),
        (Ask::UnknownCommand, _) => refused(exception::ILLEGAL_VALUE),
        (Ask::SeqForward, _) => ok(None, E::SeqWritten),
        (Ask::SeqBack, Idle) => ok(None, E::SeqWritten),
        (Ask::SeqPastRing | Ask::SeqBack | Ask::SeqHalf | Ask::CommittedSlot, _) => {
            refused(exception::ILLEGAL_VALUE)
        }
        (Ask::ReadOnly | Ask::Reserved | Ask::ReadPastMap, _) => {
            refused(exception::ILLEGAL_ADDRESS)
        }
        (Ask::ReadTooMany, _) => refused(exception::ILLEGAL_VALUE),
        (Ask::UnknownFunction, _) => refused(exception::ILLEGAL_FUNCTION),
        // start, hold, resume, clear fault outside their states; command 0; free slots; reads
        _ => ok(None, E::None),
    }
}

/// The cell as the document writes it.
pub fn cell_text(c: Cell) -> String {
    if let Some(code) = c.exception {
        return format!("0x{code:02X}");
    }
    let mut t = match c.next {
        Some(s) => format!("→ {}", state_name(s)),
        None => "ok".to_string(),
    };
    match c.effect {
        Effect::None | Effect::SeqWritten => {}
        Effect::WriteToConsumed => t.push_str(", write := consumed"),
        Effect::ConsumedToWrite => t.push_str(", consumed := write"),
        Effect::FaultCleared => t.push_str(", fault := 0, write := consumed"),
    }
    t
}

fn state_name(s: ModbusState) -> &'static str {
    match s {
        Idle => "idle",
        Running => "running",
        Hold => "hold",
        Fault => "fault",
    }
}

/// The state table as docs/modbus.md carries it.
pub fn markdown_table() -> String {
    super::markdown(
        "request \\ state",
        &ASKS,
        &STATES,
        |a| a.text().to_string(),
        |s| format!("{} ({})", state_name(s), s as u16),
        |a, s| cell_text(cell(a, s)),
    )
}

/// A block that keeps the machine busy for ten minutes.
fn long_dwell() -> MotionBlock {
    MotionBlock {
        kind: BlockKind::Dwell,
        target: [0; 3],
        feed: 600_000,
        center: [0, 0],
    }
}

struct Device<'a> {
    link: &'a mut ModbusLink,
}

impl Device<'_> {
    fn base(&self) -> u16 {
        self.link.settings().base_address
    }
    fn split(&self, v: u32) -> [u16; 2] {
        self.link.settings().word_order.split(v)
    }
    async fn header(&mut self) -> Result<Status, String> {
        self.link
            .read_status()
            .await
            .map_err(|e| format!("reading the header: {e}"))
    }
    async fn write(&mut self, addr: u16, words: Vec<u16>) -> Result<(), String> {
        self.link
            .call(&Request::Write { addr, words })
            .await
            .map(|_| ())
            .map_err(|e| format!("setting up: {e}"))
    }
    /// Write sequence := `seq` (with a command before it, if any), in one write.
    async fn commit(&mut self, command: Option<Command>, seq: u32) -> Result<(), String> {
        let mut words: Vec<u16> = command.map(|c| vec![c as u16]).unwrap_or_default();
        words.extend(self.split(seq));
        let addr = self.base()
            + if command.is_some() {
                reg::COMMAND
            } else {
                reg::WRITE_SEQ
            };
        self.write(addr, words).await
    }
    async fn wait_for(&mut self, state: ModbusState) -> Result<Status, String> {
        for _ in 0..400 {
            let h = self.header().await?;
            if h.state == state as u16 {
                return Ok(h);
            }
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        Err(format!(
            "the device never reached state {}",
            state_name(state)
        ))
    }
    fn layout(&self, h: &Status) -> Layout {
        Layout {
            base: self.base(),
            capacity: h.capacity,
        }
    }

    /// Takes a fresh (idle, sequences 0) device to `state`.
    async fn reach(&mut self, state: ModbusState) -> Result<(), String> {
        let h = self.header().await?;
        if h.state != Idle as u16 || h.write_seq != 0 || h.consumed_seq != 0 {
            return Err("the device is not fresh (idle, sequences 0)".into());
        }
        let layout = self.layout(&h);
        let order = self.link.settings().word_order;
        match state {
            Idle => {}
            Running | Hold => {
                // blocks 1 and 2: ten-minute dwells; committed and started
                let mut words = long_dwell().encode(1, order).to_vec();
                words.extend(long_dwell().encode(2, order));
                self.write(layout.slot_address(0), words).await?;
                self.commit(Some(Command::Start), 2).await?;
                self.wait_for(Running).await?;
                if state == Hold {
                    self.write(self.base() + reg::COMMAND, vec![Command::Hold as u16])
                        .await?;
                    self.wait_for(Hold).await?;
                }
            }
            Fault => {
                // block 1 with a move type the map does not have: fault 2 when it comes up
                let mut words = long_dwell().encode(1, order).to_vec();
                words[2] = 9;
                self.write(layout.slot_address(0), words).await?;
                self.commit(Some(Command::Start), 1).await?;
                self.wait_for(Fault).await?;
            }
        }
        Ok(())
    }
}

/// Takes a fresh device (idle, both sequences 0, as after power-up) to `state`, sends `ask`,
/// and checks the reply, the next state and the registers against the table. `link` must
/// be connected to that device and speak its base address and word order.
pub async fn check(link: &mut ModbusLink, state: ModbusState, ask: Ask) -> Result<(), String> {
    let want = cell(ask, state);
    let mut d = Device { link };
    d.reach(state).await?;
    // What some rows need beyond the state: a committed block, or a write sequence above 0.
    if state == Idle {
        match ask {
            Ask::SeqBack | Ask::Sync => d.commit(None, 2).await?,
            Ask::CommittedSlot => d.commit(None, 1).await?,
            _ => {}
        }
    }
    let before = d.header().await?;
    let base = d.base();
    let layout = d.layout(&before);
    let zeros = vec![0u16; BLOCK_REGISTERS as usize];
    let mut written = None;
    let mut seq = |v: u32| {
        written = Some(v);
        d.split(v).to_vec()
    };
    let command = |c: u16| Request::Write {
        addr: base + reg::COMMAND,
        words: vec![c],
    };
    let request = match ask {
        Ask::Start => command(Command::Start as u16),
        Ask::Hold => command(Command::Hold as u16),
        Ask::Resume => command(Command::Resume as u16),
        Ask::Stop => command(Command::Stop as u16),
        Ask::ClearFault => command(Command::ClearFault as u16),
        Ask::Sync => command(Command::Sync as u16),
        Ask::NoCommand => command(0),
        Ask::UnknownCommand => command(7),
        Ask::SeqForward => Request::Write {
            addr: base + reg::WRITE_SEQ,
            words: seq(before.write_seq + 1),
        },
        Ask::SeqPastRing => Request::Write {
            addr: base + reg::WRITE_SEQ,
            words: seq(before.consumed_seq + before.capacity as u32 + 1),
        },
        Ask::SeqBack => Request::Write {
            addr: base + reg::WRITE_SEQ,
            words: seq(before.write_seq - 1),
        },
        Ask::SeqHalf => Request::Write {
            addr: base + reg::WRITE_SEQ + 1,
            words: vec![1],
        },
        Ask::ReadOnly => Request::Write {
            addr: base + reg::STATE,
            words: vec![0],
        },
        Ask::Reserved => Request::Write {
            addr: base + 20,
            words: vec![0],
        },
        Ask::FreeSlot => Request::Write {
            addr: layout.slot_address(before.capacity - 1),
            words: zeros,
        },
        Ask::CommittedSlot => Request::Write {
            addr: layout.slot_address(layout.slot(before.consumed_seq + 1)),
            words: zeros,
        },
        Ask::ReadHeader => Request::Read {
            addr: base,
            count: STATUS_REGISTERS,
        },
        Ask::ReadPastMap => Request::Read {
            addr: (layout.end() - 1) as u16,
            count: 2,
        },
        Ask::ReadTooMany => Request::Read {
            addr: base,
            count: 126,
        },
        Ask::UnknownFunction => Request::Other {
            function: 0x04,
            data: vec![0, 0, 0, 1],
        },
    };
    if matches!(ask, Ask::SeqForward | Ask::SeqBack | Ask::SeqPastRing) && before.capacity < 3 {
        return Err("the conformance test needs a ring of 3 blocks at least".into());
    }
    let got = d.link.call(&request).await;
    match (&got, want.exception) {
        (Ok(_), None) => {}
        (Err(ModbusError::Exception { code, .. }), Some(w)) if *code == w => {}
        (Ok(_), Some(w)) => {
            return Err(format!("a normal reply, where exception 0x{w:02X} is due"))
        }
        (Err(e), _) => return Err(format!("{e}, where {} is due", cell_text(want))),
    }
    let after = d.header().await?;
    let next = want.next.map_or(before.state, |s| s as u16);
    if after.state != next {
        return Err(format!(
            "the state word reads {} afterwards, where it must read {next}",
            after.state
        ));
    }
    let same = |what: &str, a: u32, b: u32| {
        if a == b {
            Ok(())
        } else {
            Err(format!(
                "the {what} went from {b} to {a}, where it must stay"
            ))
        }
    };
    let is = |what: &str, a: u32, b: u32| {
        if a == b {
            Ok(())
        } else {
            Err(format!("the {what} reads {a}, where it must read {b}"))
        }
    };
    // Nothing runs in these states: the consumed sequence stands still (a hold keeps the
    // block in motion unfinished).
    if want.effect != Effect::ConsumedToWrite {
        same("consumed sequence", after.consumed_seq, before.consumed_seq)?;
    }
    match want.effect {
        Effect::None => {
            same("write sequence", after.write_seq, before.write_seq)?;
            same("fault code", after.fault as u32, before.fault as u32)?;
        }
        Effect::WriteToConsumed => is("write sequence", after.write_seq, after.consumed_seq)?,
        Effect::ConsumedToWrite => is("consumed sequence", after.consumed_seq, before.write_seq)?,
        Effect::FaultCleared => {
            is("fault code", after.fault as u32, 0)?;
            is("write sequence", after.write_seq, after.consumed_seq)?;
        }
        Effect::SeqWritten => is("write sequence", after.write_seq, written.unwrap_or(0))?,
    }
    Ok(())
}
