//! The ring protocol of docs/modbus.md over a session: checks the map, starts a job at the host's sequence, fills the ring, commits and starts, follows the consumed sequence, and after a failure resynchronises so that no block is lost or executed twice.

use super::frame::{exception, Request, Response};
use super::map::{
    fault_name, reg, BlockKind, Command, Layout, ModbusState, MotionBlock, Status, WordOrder,
    BLOCK_REGISTERS, MAP_VERSION, MAX_READ_REGISTERS, STATUS_REGISTERS,
};
use super::session::{Backoff, Session};
use super::settings::{ModbusError, ModbusSettings};
use crate::link::{Control, DeviceState, LinkEvent, MachineStatus, OperatorReason, StreamEnd};

/// How long the device may leave requests unanswered before the link reports it as not
/// answering (it gives up after `retries` failed attempts in a row).
pub const NOT_ANSWERING_AFTER: Duration = Duration::from_secs(1);
use std::time::{Duration, Instant};
use tokio::sync::{mpsc, watch};

/// Where a stream stands, as the host knows it.
#[derive(Debug)]
struct Progress {
    /// Every block up to this sequence is in the ring with verified contents.
    written: u32,
    /// The write sequence the device last confirmed.
    committed: u32,
    /// Highest sequence a write may have touched (partially, if it failed).
    touched: u32,
    /// The consumed sequence last reported as acknowledged.
    acked: u32,
    started: bool,
    synced: bool,
    last_state: Option<u16>,
    last_status: Option<Instant>,
    /// What the device last reported, and when it last answered at all.
    seen: MachineStatus,
    answered: Instant,
    /// A header read moments ago together with a write (FC23), for the next round.
    status: Option<Status>,
    /// The tool block the device holds at for the operator, and whether the operator's
    /// hold has come since (only a resume after it releases the device).
    tool_stop: Option<(u32, bool)>,
    /// The tool block last reported to the daemon as waiting for the operator.
    tool_reported: Option<u32>,
    /// The operator's control changed while the last round waited (the wait's `changed()`
    /// marks the change seen, so the next round's `has_changed` no longer says so).
    control_woke: bool,
}

/// The tool the device holds at for the operator: it holds, and its next block is a tool
/// block (docs/modbus.md, rule 10a).
fn tool_stop(s: &Status, blocks: &[MotionBlock]) -> Option<u32> {
    let next = blocks.get(s.consumed_seq as usize)?;
    (s.state == ModbusState::Hold as u16 && next.kind == BlockKind::ToolChange).then_some(next.feed)
}

/// The ring protocol's side of one link: the map's place and the device's abilities.
pub(crate) struct Ring {
    base: u16,
    order: WordOrder,
    max_write: u16,
    poll: Duration,
    layout: Layout,
    /// FC23 may be tried.
    allow_read_write: bool,
    /// What the device said to FC23: `None` until it was asked.
    read_write: Option<bool>,
    pub(super) target: String,
    /// How long the device may be silent before a stream gives up (`None`: after the
    /// backoff's retries), and the longest wait between attempts meanwhile.
    silent_timeout: Option<Duration>,
    backoff_max: Duration,
    /// Where the sync that hands the device a program is journaled first (see `attach.rs`).
    pub(crate) journal: Option<Box<dyn crate::link::SendJournal>>,
}

impl Ring {
    pub(crate) fn new(s: &ModbusSettings) -> Ring {
        Ring {
            base: s.base_address,
            order: s.word_order,
            max_write: s.max_write_registers,
            poll: s.poll_interval,
            layout: Layout {
                base: s.base_address,
                capacity: 0,
            },
            allow_read_write: s.read_write,
            read_write: None,
            target: format!("Modbus device {} unit {}", s.transport, s.unit_id),
            silent_timeout: s.silent_timeout,
            backoff_max: s.backoff_max,
            journal: None,
        }
    }

    pub(crate) fn uses_read_write(&self) -> Option<bool> {
        if self.allow_read_write {
            self.read_write
        } else {
            Some(false)
        }
    }

    fn protocol(&self, message: String) -> ModbusError {
        ModbusError::Protocol {
            target: self.target.clone(),
            message,
        }
    }

    /// Names a request in the map's words, for messages.
    pub(crate) fn describe(&self, req: &Request) -> String {
        match req {
            Request::Read { addr, count } => {
                format!("read of {}", self.layout.describe(*addr, *count))
            }
            Request::Write { addr, words } => {
                format!(
                    "write of {}",
                    self.layout.describe(*addr, words.len() as u16)
                )
            }
            Request::WriteSingle { addr, .. } => {
                format!("write of {}", self.layout.describe(*addr, 1))
            }
            Request::ReadWrite {
                read_addr,
                read_count,
                write_addr,
                words,
            } => format!(
                "write of {} with a read of {}",
                self.layout.describe(*write_addr, words.len() as u16),
                self.layout.describe(*read_addr, *read_count)
            ),
            Request::Other { function, .. } => format!("request of function 0x{function:02X}"),
        }
    }

    async fn read(
        &mut self,
        session: &mut Session,
        addr: u16,
        count: u16,
    ) -> Result<Vec<u16>, ModbusError> {
        let req = Request::Read { addr, count };
        match session.call(&req, &self.describe(&req)).await? {
            Response::Read(v) => Ok(v),
            _ => unreachable!("the transport matched the reply's function"),
        }
    }

    async fn write(
        &mut self,
        session: &mut Session,
        addr: u16,
        words: Vec<u16>,
    ) -> Result<(), ModbusError> {
        let req = Request::Write { addr, words };
        session.call(&req, &self.describe(&req)).await.map(|_| ())
    }

    /// Writes `words` at `addr` (header registers: a command and/or the write sequence) and
    /// reads the header after it: one FC23 where the device takes it, else FC16 then FC3.
    async fn write_then_status(
        &mut self,
        session: &mut Session,
        addr: u16,
        words: Vec<u16>,
    ) -> Result<Status, ModbusError> {
        if self.allow_read_write && self.read_write != Some(false) {
            let req = Request::ReadWrite {
                read_addr: self.base,
                read_count: STATUS_REGISTERS,
                write_addr: addr,
                words: words.clone(),
            };
            match session.call(&req, &self.describe(&req)).await {
                Ok(Response::ReadWrite(v)) => {
                    self.read_write = Some(true);
                    return self.check_header(&v);
                }
                Ok(_) => unreachable!("the transport matched the reply's function"),
                // A device that does not know FC23 carried nothing out: do it in two.
                Err(ModbusError::Exception { code, .. })
                    if code == exception::ILLEGAL_FUNCTION && self.read_write.is_none() =>
                {
                    self.read_write = Some(false);
                }
                Err(e) => return Err(e),
            }
        }
        self.write(session, addr, words).await?;
        self.read_status(session).await
    }

    /// Writes the command register. FC16 rather than FC6: the register reads back 0 once
    /// the device acted, and some devices (pymodbus among them) echo that 0 in an FC6 reply.
    async fn command(&mut self, session: &mut Session, c: Command) -> Result<(), ModbusError> {
        self.write(session, self.base + reg::COMMAND, vec![c as u16])
            .await
    }

    /// Clears a device fault (command 5).
    pub(crate) async fn clear_fault(&mut self, session: &mut Session) -> Result<(), ModbusError> {
        self.command(session, Command::ClearFault).await
    }

    /// Reads the header and checks that it is the map this link speaks.
    pub(crate) async fn read_status(
        &mut self,
        session: &mut Session,
    ) -> Result<Status, ModbusError> {
        let r = self.read(session, self.base, STATUS_REGISTERS).await?;
        self.check_header(&r)
    }

    fn check_header(&mut self, r: &[u16]) -> Result<Status, ModbusError> {
        let s = Status::decode(r, self.order);
        if s.version != MAP_VERSION {
            return Err(self.protocol(format!(
                "holding register {} (map version) reads {}, but this link speaks version {MAP_VERSION}; check the base address",
                self.base + reg::VERSION,
                s.version
            )));
        }
        if s.block_size != BLOCK_REGISTERS {
            return Err(self.protocol(format!(
                "holding register {} (block size) reads {}, but map version 1 has {BLOCK_REGISTERS}-register blocks",
                self.base + reg::BLOCK_SIZE,
                s.block_size
            )));
        }
        let layout = Layout {
            base: self.base,
            capacity: s.capacity,
        };
        if s.capacity == 0 || layout.end() > 0x1_0000 {
            return Err(self.protocol(format!(
                "holding register {} (ring capacity) reads {}, which does not fit the address space above base {}",
                self.base + reg::CAPACITY,
                s.capacity,
                self.base
            )));
        }
        if ModbusState::from_register(s.state).is_none() {
            return Err(self.protocol(format!(
                "holding register {} (state word) reads {}, which is no state of the map",
                self.base + reg::STATE,
                s.state
            )));
        }
        self.layout = layout;
        Ok(s)
    }

    /// Reads the sequence numbers and contents of ring slots for `first..=last` (at most
    /// one ring's worth) and says for each whether it holds that block of `blocks`.
    pub(crate) async fn slots_match(
        &mut self,
        session: &mut Session,
        blocks: &[MotionBlock],
        first: u32,
        last: u32,
    ) -> Result<Vec<bool>, ModbusError> {
        let mut out = Vec::new();
        for (start_seq, regs_run) in self.runs(first, last) {
            let addr = self.layout.slot_address(self.layout.slot(start_seq));
            let mut regs = Vec::with_capacity(regs_run as usize);
            let per_read = MAX_READ_REGISTERS / BLOCK_REGISTERS * BLOCK_REGISTERS;
            let mut off = 0u16;
            while off < regs_run {
                let n = per_read.min(regs_run - off);
                regs.extend(self.read(session, addr + off, n).await?);
                off += n;
            }
            for (k, chunk) in regs.chunks(BLOCK_REGISTERS as usize).enumerate() {
                let seq = start_seq + k as u32;
                let want = blocks[seq as usize - 1].encode(seq, self.order);
                out.push(chunk == want);
            }
        }
        Ok(out)
    }

    /// Splits sequences `first..=last` into runs of adjacent ring slots: (first seq, registers).
    fn runs(&self, first: u32, last: u32) -> Vec<(u32, u16)> {
        let mut runs = Vec::new();
        let mut seq = first;
        while seq <= last {
            let slot = self.layout.slot(seq);
            let n = (last - seq + 1).min((self.layout.capacity - slot) as u32);
            runs.push((seq, n as u16 * BLOCK_REGISTERS));
            seq += n;
        }
        runs
    }

    /// Writes blocks `first..=last` into their slots, in writes of `max_write_registers`.
    async fn write_blocks(
        &mut self,
        session: &mut Session,
        blocks: &[MotionBlock],
        first: u32,
        last: u32,
    ) -> Result<(), ModbusError> {
        for (start_seq, regs_run) in self.runs(first, last) {
            let addr = self.layout.slot_address(self.layout.slot(start_seq));
            let n_blocks = regs_run / BLOCK_REGISTERS;
            let mut regs = Vec::with_capacity(regs_run as usize);
            for k in 0..n_blocks as u32 {
                let seq = start_seq + k;
                regs.extend_from_slice(&blocks[seq as usize - 1].encode(seq, self.order));
            }
            let per = self.max_write as usize;
            for (i, chunk) in regs.chunks(per).enumerate() {
                let at = addr + (i * per) as u16;
                self.write(session, at, chunk.to_vec()).await?;
            }
        }
        Ok(())
    }

    /// After a failure (or when a stream finds the device busy with this job): reads where
    /// the device is and which slots hold the right blocks, and sets the progress so that
    /// only missing blocks are rewritten and nothing the device accepted is sent again.
    async fn resync(
        &mut self,
        session: &mut Session,
        blocks: &[MotionBlock],
        p: &mut Progress,
    ) -> Result<(), ModbusError> {
        let s = self.read_status(session).await?;
        let total = blocks.len() as u32;
        if s.consumed_seq < p.acked {
            return Err(self.protocol(format!(
                "the consumed sequence went back from {} to {} (did the device restart?); the job stops at block {}",
                p.acked, s.consumed_seq, p.acked
            )));
        }
        if s.write_seq != p.committed && s.write_seq != p.written {
            return Err(self.protocol(format!(
                "the write sequence reads {}, but this link last wrote {} (another master on the device?)",
                s.write_seq, p.committed
            )));
        }
        p.committed = s.write_seq;
        let last = p
            .touched
            .max(p.written)
            .min(total)
            .min(s.consumed_seq + s.capacity as u32);
        if last > s.consumed_seq {
            let ok = self
                .slots_match(session, blocks, s.consumed_seq + 1, last)
                .await?;
            let mut written = s.consumed_seq;
            for (k, good) in ok.iter().enumerate() {
                let seq = s.consumed_seq + 1 + k as u32;
                if seq <= p.committed && !good {
                    return Err(self.protocol(format!(
                        "ring slot {} does not hold block {seq}, which the device had accepted",
                        self.layout.slot(seq)
                    )));
                }
                if !good {
                    break;
                }
                written = seq;
            }
            p.written = written;
        } else {
            p.written = s.consumed_seq.max(p.committed);
        }
        p.touched = p.written;
        p.status = Some(s);
        Ok(())
    }

    /// Takes in a header: acknowledgements, status events, a device fault.
    fn observe(
        &self,
        s: &Status,
        blocks: &[MotionBlock],
        p: &mut Progress,
        events: &mpsc::UnboundedSender<LinkEvent>,
    ) -> Result<(), ModbusError> {
        if s.consumed_seq < p.acked {
            return Err(self.protocol(format!(
                "the consumed sequence went back from {} to {} (did the device restart?)",
                p.acked, s.consumed_seq
            )));
        }
        if s.consumed_seq > p.acked {
            if s.consumed_seq > p.committed.max(p.written) || s.consumed_seq as usize > blocks.len()
            {
                return Err(self.protocol(format!(
                    "the device reports block {} consumed, but only {} were committed",
                    s.consumed_seq, p.committed
                )));
            }
            p.acked = s.consumed_seq;
            let _ = events.send(LinkEvent::Acked {
                unit: p.acked as usize - 1,
            });
        }
        let due = p
            .last_status
            .is_none_or(|t| t.elapsed() >= Duration::from_millis(200));
        let mut seen = s.to_status();
        if let Some(number) = tool_stop(s, blocks) {
            let seq = s.consumed_seq + 1;
            if p.tool_reported == Some(seq) && p.tool_stop == Some((seq, true)) {
                // the operator has this stop in hand (the daemon's hold came): saying it
                // again, from a header read before the operator's resume took effect,
                // would pause the job a second time once it is resumed
                return Ok(());
            }
            p.tool_reported = Some(seq);
            // holding at a tool block: the operator loads the tool, then resumes
            seen.state = DeviceState::NeedsOperator {
                reason: OperatorReason::LoadTool {
                    number,
                    name: String::new(),
                },
            };
            seen.detail = format!("holding at block {} for tool T{number}", s.consumed_seq + 1);
        }
        if p.last_state != Some(s.state) || seen.state != p.seen.state || due {
            p.last_state = Some(s.state);
            p.last_status = Some(Instant::now());
            p.seen = seen;
            let _ = events.send(LinkEvent::Status(p.seen.clone()));
        }
        if s.state == ModbusState::Fault as u16 {
            let block = s.consumed_seq + 1;
            let detail = blocks
                .get(block as usize - 1)
                .map(|b| format!(" ({b})"))
                .unwrap_or_default();
            return Err(ModbusError::DeviceFault {
                target: self.target.clone(),
                code: s.fault,
                block,
                detail,
            });
        }
        Ok(())
    }

    /// The words of a write at the command register: `command`, then the write sequence.
    fn command_and_seq(&self, command: Command, seq: u32) -> Vec<u16> {
        let mut words = vec![command as u16];
        words.extend(self.order.split(seq));
        words
    }

    /// Before the first block: a new job (the device's consumed sequence becomes `from`),
    /// or a take-over of the device still running this program from an earlier stream.
    async fn sync(
        &mut self,
        session: &mut Session,
        blocks: &[MotionBlock],
        from: u32,
        s: Status,
        p: &mut Progress,
    ) -> Result<(), ModbusError> {
        let total = blocks.len() as u32;
        match ModbusState::from_register(s.state) {
            Some(ModbusState::Idle) => {
                // Write sequence := from, then sync, in one write (the device applies the
                // write sequence before the command).
                self.journal_sync(from, total)?;
                let words = self.command_and_seq(Command::Sync, from);
                let s = self
                    .write_then_status(session, self.base + reg::COMMAND, words)
                    .await?;
                if s.consumed_seq != from || s.write_seq != from {
                    return Err(self.protocol(format!(
                        "after the sync command the device reports consumed {} and write {}, not {from}",
                        s.consumed_seq, s.write_seq
                    )));
                }
                (p.written, p.committed, p.touched, p.acked) = (from, from, from, from);
                p.status = Some(s);
                self.journal_synced(total)?;
            }
            Some(ModbusState::Fault) => {
                return Err(self.protocol(format!(
                    "the device is in fault 0x{:04X} ({}) from before this job; clear it at the machine (command register {} = 5) and resume",
                    s.fault,
                    fault_name(s.fault),
                    self.base + reg::COMMAND
                )));
            }
            _ => {
                // Still running this program from an earlier stream: take over where it is.
                if s.consumed_seq < from || s.write_seq > total {
                    return Err(self.protocol(format!(
                        "the device is busy (state {}) with blocks {}..{} of another program; stop it first",
                        ModbusState::from_register(s.state).map_or("?", |d| d.name()),
                        s.consumed_seq,
                        s.write_seq
                    )));
                }
                (p.committed, p.written, p.touched, p.acked) =
                    (s.write_seq, s.write_seq, s.write_seq, from);
                self.resync(session, blocks, p).await?;
                p.started = true;
            }
        }
        p.synced = true;
        Ok(())
    }

    /// One round: take the header, obey the operator, then fill the ring, commit (and
    /// start) with the header read in the same request, or wait.
    #[allow(clippy::too_many_arguments)]
    async fn step(
        &mut self,
        session: &mut Session,
        blocks: &[MotionBlock],
        from: u32,
        p: &mut Progress,
        events: &mpsc::UnboundedSender<LinkEvent>,
        control: &mut watch::Receiver<Control>,
    ) -> Result<Option<StreamEnd>, ModbusError> {
        let total = blocks.len() as u32;
        let s = match p.status.take() {
            Some(s) => s,
            None => self.read_status(session).await?,
        };
        if !p.synced {
            self.sync(session, blocks, from, s, p).await?;
            return Ok(None);
        }
        let state = ModbusState::from_register(s.state);
        if matches!(state, Some(ModbusState::Running | ModbusState::Hold)) {
            p.started = true;
        }
        let command = self.base + reg::COMMAND;
        // (a change since the last round: the daemon's hold and the operator's resume can
        // both come between two rounds, and then only the resume is seen)
        let changed = std::mem::take(&mut p.control_woke) | control.has_changed().unwrap_or(false);
        let want = *control.borrow_and_update();
        // at a tool block the device waits for the operator: the daemon's hold (which the
        // job's pause sends) and then the operator's resume release it, never the run the
        // link had before the stop
        let at_tool = tool_stop(&s, blocks).map(|_| s.consumed_seq + 1);
        match at_tool {
            Some(seq) => {
                let seen_before = p.tool_stop.is_some_and(|(at, _)| at == seq);
                if !seen_before {
                    p.tool_stop = Some((seq, false));
                }
                if want == Control::Hold || (changed && seen_before) {
                    p.tool_stop = Some((seq, true));
                }
            }
            None => p.tool_stop = None,
        }
        // after the operator's part of a tool stop is known, so that it is not reported again
        self.observe(&s, blocks, p, events)?;
        let waits_for_operator = p.tool_stop.is_some_and(|(_, held)| !held);
        match want {
            Control::Cancel => {
                let s = self
                    .write_then_status(session, command, vec![Command::Stop as u16])
                    .await?;
                self.observe(&s, blocks, p, events)?;
                return Ok(Some(StreamEnd::Cancelled {
                    acked: p.acked as usize,
                }));
            }
            Control::Hold if state == Some(ModbusState::Running) => {
                let words = vec![Command::Hold as u16];
                p.status = Some(self.write_then_status(session, command, words).await?);
                return Ok(None);
            }
            Control::Run if state == Some(ModbusState::Hold) && !waits_for_operator => {
                let words = vec![Command::Resume as u16];
                p.status = Some(self.write_then_status(session, command, words).await?);
                return Ok(None);
            }
            _ => {}
        }
        if s.consumed_seq >= total && state == Some(ModbusState::Idle) {
            return Ok(Some(StreamEnd::Completed));
        }
        if s.write_seq != p.committed {
            return Err(self.protocol(format!(
                "the write sequence changed from {} to {} behind this link's back (stopped at the machine?)",
                p.committed, s.write_seq
            )));
        }
        if p.started && state == Some(ModbusState::Idle) {
            return Err(self.protocol(format!(
                "the device went idle after block {} of {total} (stopped at the machine?)",
                s.consumed_seq
            )));
        }
        let mut worked = false;
        let in_ring = p.written - s.consumed_seq;
        let room = (s.capacity as u32).saturating_sub(in_ring);
        if p.written < total && room > 0 {
            // All the room at once: fewer, fuller writes and one commit per ring's worth.
            let last = (p.written + room).min(total);
            p.touched = p.touched.max(last);
            self.write_blocks(session, blocks, p.written + 1, last)
                .await?;
            p.written = last;
            worked = true;
        }
        let start = !p.started && p.written > s.consumed_seq && state == Some(ModbusState::Idle);
        if p.written > p.committed || start {
            let (addr, words) = if start {
                (command, self.command_and_seq(Command::Start, p.written))
            } else {
                (
                    self.base + reg::WRITE_SEQ,
                    self.order.split(p.written).to_vec(),
                )
            };
            p.status = Some(self.write_then_status(session, addr, words).await?);
            p.committed = p.written;
            p.started |= start;
            worked = true;
        }
        if !worked {
            // Wake early for the operator; a dropped control sender just leaves the poll.
            let operator = async {
                if control.changed().await.is_err() {
                    std::future::pending::<()>().await
                }
            };
            tokio::select! {
                _ = tokio::time::sleep(self.poll) => {}
                _ = operator => p.control_woke = true,
            }
        }
        Ok(None)
    }

    /// Streams `blocks` from unit `from` on (unit `i` travels as sequence `i + 1`).
    pub(crate) async fn stream(
        &mut self,
        session: &mut Session,
        mut backoff: Backoff,
        blocks: &[MotionBlock],
        from: usize,
        events: mpsc::UnboundedSender<LinkEvent>,
        mut control: watch::Receiver<Control>,
    ) -> Result<StreamEnd, ModbusError> {
        if blocks.len() >= u32::MAX as usize {
            return Err(ModbusError::Settings(format!(
                "a program of {} blocks does not fit 32-bit sequence numbers",
                blocks.len()
            )));
        }
        let from = from.min(blocks.len()) as u32;
        let mut p = Progress {
            written: from,
            committed: from,
            touched: from,
            acked: from,
            started: false,
            synced: false,
            last_state: None,
            last_status: None,
            seen: MachineStatus::default(),
            answered: Instant::now(),
            status: None,
            tool_stop: None,
            tool_reported: None,
            control_woke: false,
        };
        let mut resync = false;
        loop {
            let r = if resync {
                self.resync(session, blocks, &mut p).await.map(|()| None)
            } else {
                self.step(session, blocks, from, &mut p, &events, &mut control)
                    .await
            };
            match r {
                Ok(Some(end)) => return Ok(end),
                Ok(None) => {
                    backoff.reset();
                    resync = false;
                    p.answered = Instant::now();
                }
                Err(e) if e.is_retryable() => {
                    p.status = None;
                    let silent = p.answered.elapsed();
                    if matches!(e, ModbusError::Timeout { .. }) && silent >= NOT_ANSWERING_AFTER {
                        let _ = events.send(LinkEvent::Status(MachineStatus::not_answering(
                            &p.seen, silent,
                        )));
                    }
                    let wait = match (backoff.failed(), self.silent_timeout) {
                        (_, Some(t)) if silent >= t => None,
                        (w, Some(_)) => Some(w.unwrap_or(self.backoff_max)),
                        (w, None) => w,
                    };
                    let Some(wait) = wait else {
                        return Err(ModbusError::GaveUp {
                            target: self.target.clone(),
                            attempts: backoff.failures(),
                            last: Box::new(e),
                        });
                    };
                    if !e.keeps_connection() {
                        // Before the sync the device holds nothing of ours: redo the sync.
                        resync = p.synced;
                    }
                    let _ = events.send(LinkEvent::Message(format!("retrying: {e}")));
                    tokio::time::sleep(wait).await;
                }
                Err(e) => return Err(e),
            }
        }
    }
}
