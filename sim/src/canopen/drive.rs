//! A simulated CiA 402 servo drive with no I/O: frames in, frames out, driven by the SYNCs it
//! sees and by a clock for its heartbeat. It keeps an object dictionary served over SDO, the
//! NMT and power state machines, PDO mappings set over SDO, a one-deep interpolation buffer,
//! a motion model with following error, EMCY on faults, and a record of every SYNC.

use machlink_protocols::canopen::cia402::{self, Command, Mode, PowerState};
use machlink_protocols::canopen::frame::CanFrame;
use machlink_protocols::canopen::nmt::{self, classify, Cob, Emcy, NmtCommand, NmtState};
use machlink_protocols::canopen::pdo::{Mapped, COB_INVALID};
use machlink_protocols::canopen::sdo::{self, AbortCode, ObjectAccess, SdoServer};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::time::Duration;

/// A fault to inject, counted in SYNCs from the moment it is armed.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "fault", rename_all = "snake_case")]
pub enum DriveFault {
    /// The heartbeat stops after `after_syncs` SYNCs, until an NMT reset.
    Silent { after_syncs: u64 },
    /// A following error: EMCY 0x8611 and the fault state, after `after_syncs` SYNCs.
    FollowingError { after_syncs: u64 },
    /// The next SDO access to `index`:`sub` is aborted with `code`.
    SdoAbort { index: u16, sub: u8, code: u32 },
    /// The drive misses one SYNC after `after_syncs`; it notices at the next set-point
    /// (EMCY 0x8700, fault).
    LoseSync { after_syncs: u64 },
    /// Any fault with EMCY `code` (e.g. 0x2310 over-current) after `after_syncs` SYNCs.
    Fault { after_syncs: u64, code: u16 },
}

/// What the drive did at one SYNC while operation was enabled.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SyncRecord {
    /// The SYNCs this drive has seen, this one included.
    pub sync: u64,
    /// The set-point applied at this SYNC, counts.
    pub demand: i32,
    /// Where the motor is after this cycle, counts (the motion model's value).
    pub actual: f64,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Access {
    Ro,
    Rw,
}

#[derive(Clone, Debug)]
struct Object {
    data: Vec<u8>,
    access: Access,
    mappable: bool,
}

/// Fraction of the remaining distance the motor covers each cycle.
pub const FOLLOWING_GAIN: f64 = 0.6;

/// A simulated drive.
pub struct Drive {
    pub node: u8,
    od: BTreeMap<(u16, u8), Object>,
    sdo: SdoServer,
    nmt: NmtState,
    power: PowerState,
    last_cw: u16,
    /// A set-point came by RPDO since the last SYNC.
    fresh_setpoint: bool,
    demand: i32,
    actual: f64,
    syncs: u64,
    silent: bool,
    heartbeat_due: Option<Duration>,
    now: Duration,
    armed: Vec<(u64, DriveFault)>,
    aborts: Vec<(u16, u8, u32)>,
    lose_next: bool,
    trace: Vec<SyncRecord>,
    out: Vec<CanFrame>,
}

fn obj(data: Vec<u8>, access: Access, mappable: bool) -> Object {
    Object {
        data,
        access,
        mappable,
    }
}

impl Drive {
    /// A drive at node `node`, just powered: it sends its boot-up message on the first call.
    pub fn new(node: u8) -> Drive {
        let mut d = Drive {
            node,
            od: BTreeMap::new(),
            sdo: SdoServer::new(),
            nmt: NmtState::PreOperational,
            power: PowerState::SwitchOnDisabled,
            last_cw: 0,
            fresh_setpoint: false,
            demand: 0,
            actual: 0.0,
            syncs: 0,
            silent: false,
            heartbeat_due: None,
            now: Duration::ZERO,
            armed: Vec::new(),
            aborts: Vec::new(),
            lose_next: false,
            trace: Vec::new(),
            out: Vec::new(),
        };
        d.reset(true);
        d
    }

    fn defaults(&mut self, communication: bool, application: bool) {
        use Access::*;
        let n = self.node as u32;
        let od = &mut self.od;
        if communication {
            od.retain(|(i, _), _| !(0x1000..0x2000).contains(i));
            od.insert(
                (0x1000, 0),
                obj(0x0002_0192u32.to_le_bytes().to_vec(), Ro, false),
            );
            od.insert((0x1001, 0), obj(vec![0], Ro, false));
            od.insert((0x1006, 0), obj(0u32.to_le_bytes().to_vec(), Rw, false));
            od.insert(
                (0x1008, 0),
                obj(b"machlink simulated CiA 402 drive".to_vec(), Ro, false),
            );
            od.insert((0x1017, 0), obj(0u16.to_le_bytes().to_vec(), Rw, false));
            od.insert((0x1018, 0), obj(vec![4], Ro, false));
            od.insert(
                (0x1018, 1),
                obj(0x4D4C_4E4Bu32.to_le_bytes().to_vec(), Ro, false),
            );
            od.insert((0x1018, 2), obj(402u32.to_le_bytes().to_vec(), Ro, false));
            od.insert((0x1018, 3), obj(1u32.to_le_bytes().to_vec(), Ro, false));
            od.insert((0x1018, 4), obj(n.to_le_bytes().to_vec(), Ro, false));
            // PDO 1 each way, predefined connection set; default maps controlword / statusword
            od.insert((0x1400, 0), obj(vec![2], Ro, false));
            od.insert(
                (0x1400, 1),
                obj((0x200 + n).to_le_bytes().to_vec(), Rw, false),
            );
            od.insert((0x1400, 2), obj(vec![0xFF], Rw, false));
            od.insert((0x1800, 0), obj(vec![2], Ro, false));
            od.insert(
                (0x1800, 1),
                obj((0x180 + n).to_le_bytes().to_vec(), Rw, false),
            );
            od.insert((0x1800, 2), obj(vec![0xFF], Rw, false));
            for (map, first) in [(0x1600u16, 0x6040_0010u32), (0x1A00, 0x6041_0010)] {
                od.insert((map, 0), obj(vec![1], Rw, false));
                od.insert((map, 1), obj(first.to_le_bytes().to_vec(), Rw, false));
                for s in 2..=8 {
                    od.insert((map, s), obj(vec![0; 4], Rw, false));
                }
            }
        }
        if application {
            od.insert((0x603F, 0), obj(vec![0; 2], Ro, false));
            od.insert((0x6040, 0), obj(vec![0; 2], Rw, true));
            od.insert((0x6041, 0), obj(vec![0; 2], Ro, true));
            od.insert((0x605A, 0), obj(2i16.to_le_bytes().to_vec(), Rw, false));
            od.insert((0x6060, 0), obj(vec![0], Rw, true));
            od.insert((0x6061, 0), obj(vec![0], Ro, true));
            od.insert((0x6064, 0), obj(vec![0; 4], Ro, true));
            od.insert((0x6065, 0), obj(u32::MAX.to_le_bytes().to_vec(), Rw, false));
            od.insert((0x607A, 0), obj(vec![0; 4], Rw, true));
            od.insert((0x60C1, 0), obj(vec![1], Ro, false));
            od.insert((0x60C1, 1), obj(vec![0; 4], Rw, true));
            od.insert((0x60C2, 0), obj(vec![2], Ro, false));
            od.insert((0x60C2, 1), obj(vec![1], Rw, false));
            od.insert((0x60C2, 2), obj(vec![(-3i8) as u8], Rw, false));
            od.insert((0x60F4, 0), obj(vec![0; 4], Ro, true));
        }
    }

    /// Reset node (`application`) or communication: defaults, boot-up, pre-operational.
    fn reset(&mut self, application: bool) {
        self.defaults(true, application);
        if application {
            self.power = PowerState::SwitchOnDisabled;
            self.last_cw = 0;
            let pos = self.actual.round() as i32;
            self.set_i32(0x6064, 0, pos);
        }
        self.silent = false;
        self.heartbeat_due = None;
        self.sdo = SdoServer::new();
        self.fresh_setpoint = false;
        self.out
            .push(nmt::heartbeat_frame(self.node, NmtState::BootUp));
        self.nmt = NmtState::PreOperational;
        self.update_statusword();
    }

    fn get(&self, index: u16, sub: u8) -> &[u8] {
        self.od
            .get(&(index, sub))
            .map(|o| o.data.as_slice())
            .unwrap_or(&[])
    }
    fn get_u32(&self, index: u16, sub: u8) -> u32 {
        let d = self.get(index, sub);
        let mut b = [0u8; 4];
        for (i, x) in d.iter().take(4).enumerate() {
            b[i] = *x;
        }
        u32::from_le_bytes(b)
    }
    fn set_raw(&mut self, index: u16, sub: u8, data: &[u8]) {
        if let Some(o) = self.od.get_mut(&(index, sub)) {
            let n = o.data.len();
            o.data.clear();
            o.data.extend_from_slice(&data[..data.len().min(n)]);
            o.data.resize(n, 0);
        }
    }
    fn set_i32(&mut self, index: u16, sub: u8, v: i32) {
        self.set_raw(index, sub, &v.to_le_bytes());
    }

    fn mode(&self) -> Option<Mode> {
        Mode::from_code(self.get(0x6060, 0).first().copied().unwrap_or(0) as i8)
    }

    fn update_statusword(&mut self) {
        let mut sw = self.power.statusword() | cia402::SW_REMOTE;
        if self.power == PowerState::OperationEnabled
            && self.mode() == Some(Mode::InterpolatedPosition)
            && self.last_cw & cia402::CW_ENABLE_IP != 0
        {
            sw |= cia402::SW_IP_ACTIVE;
        }
        self.set_raw(0x6041, 0, &sw.to_le_bytes());
    }

    /// Goes to the fault state with EMCY `code`.
    fn fault(&mut self, code: u16) {
        if self.power == PowerState::Fault {
            return;
        }
        self.power = PowerState::Fault;
        self.demand = self.actual.round() as i32;
        self.set_raw(0x603F, 0, &code.to_le_bytes());
        let register = 0x01 | if code & 0xF000 == 0x8000 { 0x10 } else { 0x00 };
        self.set_raw(0x1001, 0, &[register]);
        self.out.push(
            Emcy {
                node: self.node,
                code,
                register,
                vendor: [0; 5],
            }
            .frame(),
        );
        self.update_statusword();
    }

    fn controlword(&mut self, cw: u16) {
        let cmd = Command::from_controlword(cw, self.last_cw);
        self.last_cw = cw;
        if let Some(next) = cmd.and_then(|c| self.power.on(c)) {
            if self.power == PowerState::Fault && next == PowerState::SwitchOnDisabled {
                self.set_raw(0x603F, 0, &[0, 0]);
                self.set_raw(0x1001, 0, &[0]);
                self.out.push(
                    Emcy {
                        node: self.node,
                        code: 0,
                        register: 0,
                        vendor: [0; 5],
                    }
                    .frame(),
                );
            }
            if next == PowerState::OperationEnabled {
                // a drive enables at standstill where it is
                self.demand = self.actual.round() as i32;
            }
            self.power = next;
            if next == PowerState::QuickStopActive {
                // the motor stops where it is (the model's quick stop ramp takes no time);
                // option codes 1–4 then go to switch on disabled, 5–8 stay in quick stop
                self.demand = self.actual.round() as i32;
                let code = i16::from_le_bytes([self.get(0x605A, 0)[0], self.get(0x605A, 0)[1]]);
                if (1..=4).contains(&code) {
                    self.power = PowerState::SwitchOnDisabled;
                }
            }
        }
        self.update_statusword();
    }

    /// Arms a fault, counted from now.
    pub fn inject(&mut self, fault: DriveFault) {
        match fault {
            DriveFault::SdoAbort { index, sub, code } => self.aborts.push((index, sub, code)),
            DriveFault::Silent { after_syncs }
            | DriveFault::FollowingError { after_syncs }
            | DriveFault::LoseSync { after_syncs }
            | DriveFault::Fault { after_syncs, .. } => {
                self.armed.push((self.syncs + after_syncs, fault))
            }
        }
    }

    /// What the drive did at each SYNC while operation was enabled.
    pub fn trace(&self) -> &[SyncRecord] {
        &self.trace
    }

    /// Forgets the record.
    pub fn clear_trace(&mut self) {
        self.trace.clear();
    }

    /// SYNCs seen so far.
    pub fn syncs(&self) -> u64 {
        self.syncs
    }

    pub fn power_state(&self) -> PowerState {
        self.power
    }

    pub fn nmt_state(&self) -> NmtState {
        self.nmt
    }

    /// Frames the drive sends now (its boot-up after a reset, answers).
    pub fn take_output(&mut self, out: &mut Vec<CanFrame>) {
        out.append(&mut self.out);
    }

    /// The clock moved to `now`: the heartbeat, when due.
    pub fn tick(&mut self, now: Duration, out: &mut Vec<CanFrame>) {
        self.now = now;
        let period = self.get_u32(0x1017, 0) & 0xFFFF;
        if period == 0 || self.silent {
            self.heartbeat_due = None;
        } else {
            let due = *self.heartbeat_due.get_or_insert(now);
            if now >= due {
                self.out.push(nmt::heartbeat_frame(self.node, self.nmt));
                self.heartbeat_due = Some(now + Duration::from_millis(period as u64));
            }
        }
        self.take_output(out);
    }

    /// Takes one frame from the bus; the answers go to `out`.
    pub fn on_frame(&mut self, f: &CanFrame, out: &mut Vec<CanFrame>) {
        self.frame(f);
        self.take_output(out);
    }

    fn frame(&mut self, f: &CanFrame) {
        let Some(cob) = f.cob_id() else { return };
        match classify(cob) {
            Cob::Nmt => {
                if let Some((cmd, node)) = NmtCommand::parse(f) {
                    if node == 0 || node == self.node {
                        self.nmt_command(cmd);
                    }
                }
            }
            Cob::Sync if nmt::is_sync(f) => self.sync(),
            Cob::SdoRequest(n) if n == self.node && self.nmt != NmtState::Stopped => {
                let mut server = std::mem::take(&mut self.sdo);
                let reply = server.on_request(f.data(), self);
                self.sdo = server;
                if let Some(r) = reply {
                    self.out
                        .push(CanFrame::new(sdo::response_cob(self.node), &r).expect("8 bytes"));
                }
            }
            _ if self.nmt == NmtState::Operational => {
                let rpdo_cob = self.get_u32(0x1400, 1);
                if rpdo_cob & COB_INVALID == 0 && cob as u32 == rpdo_cob & 0x7FF {
                    self.rpdo(f.data());
                }
            }
            _ => {}
        }
    }

    fn nmt_command(&mut self, cmd: NmtCommand) {
        match cmd {
            NmtCommand::Start => self.nmt = NmtState::Operational,
            NmtCommand::Stop => self.nmt = NmtState::Stopped,
            NmtCommand::PreOperational => self.nmt = NmtState::PreOperational,
            NmtCommand::ResetNode => self.reset(true),
            NmtCommand::ResetCommunication => self.reset(false),
        }
        // the state change shows at once
        if self.heartbeat_due.is_some() {
            self.heartbeat_due = Some(self.now);
        }
    }

    fn mapping(&self, map: u16) -> Vec<Mapped> {
        let n = self.get(map, 0).first().copied().unwrap_or(0).min(8);
        (1..=n)
            .map(|s| Mapped::from_word(self.get_u32(map, s)))
            .collect()
    }

    fn rpdo(&mut self, data: &[u8]) {
        let mut bit = 0usize;
        for m in self.mapping(0x1600) {
            let bytes = (m.bits as usize).div_ceil(8);
            if !bit.is_multiple_of(8) || bit / 8 + bytes > data.len() {
                // a frame shorter than its mapping (CiA 301: EMCY 0x8210)
                self.fault(0x8210);
                return;
            }
            let v = data[bit / 8..bit / 8 + bytes].to_vec();
            let (i, s) = (m.entry.index, m.entry.sub);
            if (i, s) == (0x60C1, 1) || (i, s) == (0x607A, 0) {
                if self.fresh_setpoint && self.power == PowerState::OperationEnabled {
                    // a second set-point before a SYNC applied the first: a SYNC went missing
                    self.fault(0x8700);
                }
                self.fresh_setpoint = true;
            }
            if (i, s) == (0x6040, 0) {
                self.controlword(u16::from_le_bytes([v[0], *v.get(1).unwrap_or(&0)]));
            } else {
                self.set_raw(i, s, &v);
            }
            bit += m.bits as usize;
        }
    }

    fn sync(&mut self) {
        self.syncs += 1;
        let now = self.syncs;
        let due: Vec<DriveFault> = self
            .armed
            .iter()
            .filter(|(at, _)| *at <= now)
            .map(|(_, f)| f.clone())
            .collect();
        self.armed.retain(|(at, _)| *at > now);
        for f in due {
            match f {
                DriveFault::Silent { .. } => self.silent = true,
                DriveFault::FollowingError { .. } => self.fault(0x8611),
                DriveFault::LoseSync { .. } => self.lose_next = true,
                DriveFault::Fault { code, .. } => self.fault(code),
                DriveFault::SdoAbort { .. } => {}
            }
        }
        if self.lose_next {
            // this SYNC never reached the drive
            self.lose_next = false;
            return;
        }
        if self.nmt != NmtState::Operational {
            return;
        }
        self.fresh_setpoint = false;
        let enabled = self.power == PowerState::OperationEnabled;
        if enabled {
            match self.mode() {
                Some(Mode::InterpolatedPosition) if self.last_cw & cia402::CW_ENABLE_IP != 0 => {
                    self.demand = self.get_u32(0x60C1, 1) as i32;
                }
                Some(Mode::CyclicSynchronousPosition) => {
                    self.demand = self.get_u32(0x607A, 0) as i32;
                }
                _ => {}
            }
            self.actual += FOLLOWING_GAIN * (self.demand as f64 - self.actual);
        }
        let following = self.demand as f64 - self.actual;
        self.set_i32(0x6064, 0, self.actual.round() as i32);
        self.set_i32(0x60F4, 0, following.round() as i32);
        if enabled {
            self.trace.push(SyncRecord {
                sync: now,
                demand: self.demand,
                actual: self.actual,
            });
            let window = self.get_u32(0x6065, 0);
            if window != u32::MAX && following.abs() > window as f64 {
                self.fault(0x8611);
            }
        }
        // TPDO 1 on every n-th SYNC (transmission types 1–240)
        let cob = self.get_u32(0x1800, 1);
        let ty = self.get(0x1800, 2).first().copied().unwrap_or(0);
        if cob & COB_INVALID == 0 && (1..=240).contains(&ty) && now.is_multiple_of(ty as u64) {
            let mut data = Vec::with_capacity(8);
            for m in self.mapping(0x1A00) {
                let bytes = (m.bits as usize).div_ceil(8);
                let mut v = self.get(m.entry.index, m.entry.sub).to_vec();
                v.resize(bytes, 0);
                data.extend_from_slice(&v);
            }
            data.truncate(8);
            self.out
                .push(CanFrame::new((cob & 0x7FF) as u16, &data).expect("at most 8 bytes"));
        }
    }

    /// Whether mapping `map` may take the entries 1..=`count`.
    fn check_mapping(&self, map: u16, count: u8) -> Result<(), AbortCode> {
        if count > 8 {
            return Err(AbortCode::PDO_TOO_LONG);
        }
        let mut bits = 0u32;
        for s in 1..=count {
            let m = Mapped::from_word(self.get_u32(map, s));
            let o = self
                .od
                .get(&(m.entry.index, m.entry.sub))
                .ok_or(AbortCode::NOT_MAPPABLE)?;
            if !o.mappable || m.bits as usize != o.data.len() * 8 {
                return Err(AbortCode::NOT_MAPPABLE);
            }
            let writable = o.access == Access::Rw;
            if map < 0x1A00 && !writable {
                return Err(AbortCode::NOT_MAPPABLE);
            }
            bits += m.bits as u32;
        }
        if bits > 64 {
            return Err(AbortCode::PDO_TOO_LONG);
        }
        Ok(())
    }
}

impl ObjectAccess for Drive {
    fn read(&mut self, index: u16, sub: u8) -> Result<Vec<u8>, AbortCode> {
        if let Some(at) = self.aborts.iter().position(|a| (a.0, a.1) == (index, sub)) {
            return Err(AbortCode(self.aborts.remove(at).2));
        }
        match self.od.get(&(index, sub)) {
            Some(o) => Ok(o.data.clone()),
            None if self.od.keys().any(|(i, _)| *i == index) => Err(AbortCode::NO_SUBINDEX),
            None => Err(AbortCode::NO_OBJECT),
        }
    }

    fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), AbortCode> {
        if let Some(at) = self.aborts.iter().position(|a| (a.0, a.1) == (index, sub)) {
            return Err(AbortCode(self.aborts.remove(at).2));
        }
        let Some(o) = self.od.get(&(index, sub)) else {
            return Err(if self.od.keys().any(|(i, _)| *i == index) {
                AbortCode::NO_SUBINDEX
            } else {
                AbortCode::NO_OBJECT
            });
        };
        if o.access == Access::Ro {
            return Err(AbortCode::READ_ONLY);
        }
        if data.len() != o.data.len() {
            return Err(if data.len() > o.data.len() {
                AbortCode::TOO_LONG
            } else {
                AbortCode::TOO_SHORT
            });
        }
        match (index, sub) {
            (0x6040, 0) => {
                self.controlword(u16::from_le_bytes([data[0], data[1]]));
                return Ok(());
            }
            (0x6060, 0) => {
                let m = Mode::from_code(data[0] as i8).ok_or(AbortCode::INVALID_VALUE)?;
                if self.power == PowerState::OperationEnabled && self.mode() != Some(m) {
                    return Err(AbortCode::DEVICE_STATE);
                }
                self.set_raw(0x6060, 0, data);
                self.set_raw(0x6061, 0, data);
                self.update_statusword();
                return Ok(());
            }
            (0x1600 | 0x1A00, s) => {
                let comm = if index == 0x1600 { 0x1400 } else { 0x1800 };
                if self.get_u32(comm, 1) & COB_INVALID == 0 {
                    // CiA 301: a mapping changes only while its PDO is not valid
                    return Err(AbortCode::DEVICE_STATE);
                }
                if s == 0 {
                    self.check_mapping(index, data[0])?;
                } else if self.get(index, 0).first().copied().unwrap_or(0) != 0 {
                    return Err(AbortCode::DEVICE_STATE);
                }
            }
            (0x1400 | 0x1800, 1) => {
                let v = u32::from_le_bytes([data[0], data[1], data[2], data[3]]);
                let old = self.get_u32(index, 1);
                // the COB-ID itself changes only while the PDO is not valid
                if v & COB_INVALID == 0 && old & COB_INVALID == 0 && v != old {
                    return Err(AbortCode::INVALID_VALUE);
                }
            }
            _ => {}
        }
        self.set_raw(index, sub, data);
        if (index, sub) == (0x1017, 0) {
            self.heartbeat_due = Some(self.now);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use machlink_protocols::canopen::sdo::{SdoClient, SdoStep};

    fn sdo(
        d: &mut Drive,
        write: Option<(u16, u8, &[u8])>,
        read: Option<(u16, u8)>,
    ) -> Result<Vec<u8>, String> {
        let mut c = SdoClient::new();
        let mut req = match (write, read) {
            (Some((i, s, v)), _) => c.download(i, s, v),
            (_, Some((i, s))) => c.upload(i, s),
            _ => unreachable!(),
        };
        loop {
            let mut out = Vec::new();
            d.on_frame(
                &CanFrame::new(0x600 + d.node as u16, &req).unwrap(),
                &mut out,
            );
            let resp = out
                .iter()
                .find(|f| f.id() == 0x580 + d.node as u32)
                .expect("an answer");
            match c.on_response(resp.data()).map_err(|e| e.to_string())? {
                SdoStep::Send(r) => req = r,
                SdoStep::Done(v) => return Ok(v),
            }
        }
    }

    #[test]
    fn device_type_names_profile_402_and_mapping_rules_hold() {
        let mut d = Drive::new(3);
        let v = sdo(&mut d, None, Some((0x1000, 0))).unwrap();
        assert_eq!(u32::from_le_bytes(v.try_into().unwrap()) & 0xFFFF, 402);
        let name = sdo(&mut d, None, Some((0x1008, 0))).unwrap();
        assert!(String::from_utf8(name).unwrap().contains("402"));
        // mapping while the PDO is valid is refused
        let e = sdo(&mut d, Some((0x1600, 0, &[0])), None).unwrap_err();
        assert!(e.contains("present device state"), "{e}");
        let e = sdo(&mut d, Some((0x6041, 0, &[0, 0])), None).unwrap_err();
        assert!(e.contains("read-only"), "{e}");
    }
}
