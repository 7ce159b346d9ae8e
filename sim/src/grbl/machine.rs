//! The simulated GRBL controller's state: receive buffer, line protocol, planner, motion
//! in simulated time, alarms and check mode. No I/O: bytes in, bytes out, driven by a clock.

use super::interp::{clean_line, Action, Interpreter, Motion};
use super::{Executed, GrblFault, GrblSimConfig};
use std::collections::{BTreeMap, VecDeque};
use std::time::{Duration, Instant};

const BANNER: &str = "\r\nGrbl 1.1h ['$' for help]\r\n";
/// GRBL's LINE_BUFFER_SIZE: a line keeps at most 79 characters after cleaning.
const LINE_BUFFER: usize = 80;

#[derive(Clone, Debug)]
enum BlockKind {
    Motion(Executed),
    Dwell,
    Pause,
    /// A jog (`$J=`): moves like a feed move, is no program line, and 0x85 cancels it.
    Jog {
        from: [f64; 3],
        to: [f64; 3],
    },
    /// The homing cycle's move to the machine's zero (`$H`).
    Home {
        from: [f64; 3],
    },
}

#[derive(Clone, Debug)]
struct Block {
    kind: BlockKind,
    /// Simulated seconds the block takes (known once it starts: the overrides in force
    /// then decide its speed).
    duration: f64,
    elapsed: f64,
    /// Path length, mm, and the peak speed (mm/s) and acceleration of its trapezoid.
    length: f64,
    v: f64,
    a: f64,
    /// The feed it asks for, mm/min (the rapid rate for rapids), before overrides.
    feed: f64,
    rapid: bool,
    started: bool,
}

impl Block {
    /// Fraction of the path covered after `t` seconds of the block's trapezoid.
    fn fraction_at(&self, t: f64) -> f64 {
        if !self.started {
            return 0.0;
        }
        if self.length <= 0.0 || self.duration <= 0.0 {
            return 1.0;
        }
        let (v, a, l) = (self.v, self.a, self.length);
        let t_acc = v / a;
        let s = if t <= t_acc {
            0.5 * a * t * t
        } else if t <= self.duration - t_acc {
            0.5 * a * t_acc * t_acc + v * (t - t_acc)
        } else {
            let td = self.duration - t;
            l - 0.5 * a * td * td
        };
        (s / l).clamp(0.0, 1.0)
    }
}

/// The simulated controller.
pub struct Machine {
    cfg: GrblSimConfig,
    rx: VecDeque<u8>,
    pub overflows: u64,
    line: Vec<u8>,
    line_overflow: bool,
    in_comment: bool,
    /// Blocks of the line being executed that wait for planner room.
    waiting: VecDeque<Block>,
    planner: VecDeque<Block>,
    interp: Interpreter,
    /// Position at the end of the last finished block.
    pos: [f64; 3],
    alarm: Option<u8>,
    /// A critical alarm: everything but reset and status is ignored until a reset.
    critical: bool,
    check: bool,
    holding: bool,
    pub trace: Vec<Executed>,
    /// Everything the controller did that a trace shows, in order.
    pub events: Vec<super::TraceEvent>,
    /// The bytes of the line being received, comments included (for the trace).
    raw: Vec<u8>,
    /// The homing cycle runs: no line is taken until it is over.
    homing: bool,
    pub received: u64,
    pub motion_time: f64,
    last_wall: Instant,
    out: Vec<u8>,
    settings: BTreeMap<u16, String>,
    overrides: [u32; 3],
    reports: u64,
    /// Hung (`GrblFault::SilentAfterLine`) until then: nothing is read or answered.
    silent_until: Option<Instant>,
    /// Bytes lost while hung.
    pub lost_while_silent: u64,
}

impl Machine {
    pub fn new(cfg: GrblSimConfig, now: Instant) -> Machine {
        let mut settings = BTreeMap::new();
        for (k, v) in [
            (0, "10"),
            (1, "25"),
            (2, "0"),
            (3, "0"),
            (4, "0"),
            (5, "0"),
            (6, "0"),
            (10, "1"),
            (11, "0.010"),
            (12, "0.002"),
            (13, "0"),
            (20, "0"),
            (21, "0"),
            (22, "0"),
            (23, "0"),
            (24, "25.000"),
            (25, "500.000"),
            (26, "250"),
            (27, "1.000"),
            (30, "1000"),
            (31, "0"),
            (32, "0"),
            (100, "250.000"),
            (101, "250.000"),
            (102, "250.000"),
            (130, "200.000"),
            (131, "200.000"),
            (132, "200.000"),
        ] {
            settings.insert(k, v.to_string());
        }
        for k in 110..=112 {
            settings.insert(k, format!("{:.3}", cfg.max_feed));
        }
        for k in 120..=122 {
            settings.insert(k, format!("{:.3}", cfg.accel));
        }
        let mut m = Machine {
            cfg,
            rx: VecDeque::new(),
            overflows: 0,
            line: Vec::new(),
            line_overflow: false,
            in_comment: false,
            waiting: VecDeque::new(),
            planner: VecDeque::new(),
            interp: Interpreter::new(),
            pos: [0.0; 3],
            alarm: None,
            critical: false,
            check: false,
            holding: false,
            trace: Vec::new(),
            events: Vec::new(),
            raw: Vec::new(),
            homing: false,
            received: 0,
            motion_time: 0.0,
            last_wall: now,
            out: BANNER.as_bytes().to_vec(),
            settings,
            overrides: [100, 100, 100],
            reports: 0,
            silent_until: None,
            lost_while_silent: 0,
        };
        m.interp.offsets = m.cfg.work_offsets;
        m.interp.touch_plate_z = m.cfg.touch_plate_z;
        m.interp.m6_holds = m.cfg.m6_holds;
        if m.cfg.homing {
            // with homing enabled GRBL starts locked until it is homed (or unlocked)
            m.settings.insert(22, "1".into());
            m.alarm = Some(0);
            m.say("[MSG:'$H'|'$X' to unlock]");
        }
        m
    }

    /// Bytes to send to the client since the last call.
    pub fn take_output(&mut self) -> Vec<u8> {
        std::mem::take(&mut self.out)
    }

    fn say(&mut self, s: &str) {
        self.out.extend_from_slice(s.as_bytes());
        self.out.extend_from_slice(b"\r\n");
    }

    /// Whether the controller hangs at `now` (`GrblFault::SilentAfterLine`).
    fn silent(&mut self, now: Instant) -> bool {
        match self.silent_until {
            Some(t) if now < t => true,
            Some(_) => {
                self.silent_until = None;
                false
            }
            None => false,
        }
    }

    /// How long a hang starts when the next G-code line is taken, if one is due now.
    fn hang_due(&self) -> Option<f64> {
        self.cfg.faults.iter().find_map(|f| match *f {
            GrblFault::SilentAfterLine { line, seconds } if line == self.received => Some(seconds),
            _ => None,
        })
    }

    fn moving(&self) -> bool {
        !self.holding && (!self.planner.is_empty() || !self.waiting.is_empty())
    }

    /// Runs the motion forward to wall time `now`.
    pub fn advance(&mut self, now: Instant) {
        let wall = now.saturating_duration_since(self.last_wall).as_secs_f64();
        self.last_wall = self.last_wall.max(now);
        if self.holding || self.alarm.is_some() {
            return;
        }
        let mut dt = if self.cfg.time_scale.is_infinite() {
            f64::INFINITY
        } else {
            wall * self.cfg.time_scale
        };
        loop {
            self.start_front();
            let Some(front) = self.planner.front_mut() else {
                break;
            };
            if let BlockKind::Pause = front.kind {
                self.planner.pop_front();
                self.holding = true;
                break;
            }
            let left = front.duration - front.elapsed;
            if left <= dt {
                dt -= left;
                self.motion_time += left;
                let done = self.planner.pop_front().expect("front exists");
                match done.kind {
                    BlockKind::Motion(e) => {
                        self.pos = e.to;
                        self.events.push(super::TraceEvent::Executed(e.clone()));
                        self.trace.push(e);
                    }
                    BlockKind::Jog { to, .. } => {
                        self.pos = to;
                        self.interp.pos = to;
                        self.events.push(super::TraceEvent::Jogged { to });
                    }
                    BlockKind::Home { .. } => {
                        self.pos = [0.0; 3];
                        self.interp.pos = [0.0; 3];
                        self.homing = false;
                        self.alarm = None;
                        self.events.push(super::TraceEvent::Homed);
                        self.say("ok");
                    }
                    BlockKind::Dwell | BlockKind::Pause => {}
                }
            } else {
                front.elapsed += dt;
                self.motion_time += dt;
                break;
            }
        }
    }

    /// Gives the block about to run its speed: its feed (or the rapid rate) under the
    /// overrides in force now.
    fn start_front(&mut self) {
        let [feed_ov, rapid_ov, _] = self.overrides;
        let max_feed = self.cfg.max_feed;
        let Some(b) = self.planner.front_mut() else {
            return;
        };
        if b.started {
            return;
        }
        b.started = true;
        let f = if b.rapid {
            b.feed * rapid_ov as f64 / 100.0
        } else if matches!(b.kind, BlockKind::Motion(_)) {
            (b.feed * feed_ov as f64 / 100.0).min(max_feed)
        } else {
            b.feed
        };
        if let BlockKind::Motion(e) = &mut b.kind {
            e.feed = f;
        }
        if matches!(b.kind, BlockKind::Dwell | BlockKind::Pause) {
            return;
        }
        let (duration, v) = trapezoid(b.length, (f / 60.0).max(1e-6), b.a);
        b.duration = duration;
        b.v = v;
    }

    /// Wall time until the next block finishes, if motion is under way.
    pub fn next_event(&self) -> Option<std::time::Duration> {
        if self.holding || self.alarm.is_some() || self.cfg.time_scale.is_infinite() {
            return None;
        }
        let f = self.planner.front()?;
        let secs = ((f.duration - f.elapsed) / self.cfg.time_scale).max(0.0);
        Some(std::time::Duration::from_secs_f64(secs.min(3600.0)))
    }

    /// Where the tool is now.
    pub fn position(&self) -> [f64; 3] {
        let Some(f) = self.planner.front() else {
            return self.pos;
        };
        let t = f.fraction_at(f.elapsed);
        let line = |from: [f64; 3], to: [f64; 3]| -> [f64; 3] {
            std::array::from_fn(|k| from[k] + (to[k] - from[k]) * t)
        };
        let e = match &f.kind {
            BlockKind::Motion(e) => e,
            BlockKind::Jog { from, to } => return line(*from, *to),
            BlockKind::Home { from } => return line(*from, [0.0; 3]),
            _ => return self.pos,
        };
        match (e.motion, e.center) {
            (Motion::ArcCw | Motion::ArcCcw, Some(c)) => {
                let sweep = arc_sweep(e.from, e.to, c, e.motion == Motion::ArcCcw);
                let a0 = (e.from[1] - c[1]).atan2(e.from[0] - c[0]);
                let r = (e.from[0] - c[0]).hypot(e.from[1] - c[1]);
                let ang = a0 + sweep * t;
                [
                    c[0] + r * ang.cos(),
                    c[1] + r * ang.sin(),
                    e.from[2] + (e.to[2] - e.from[2]) * t,
                ]
            }
            _ => std::array::from_fn(|k| e.from[k] + (e.to[k] - e.from[k]) * t),
        }
    }

    fn state_word(&self) -> &'static str {
        if self.homing {
            "Home"
        } else if self.alarm.is_some() {
            "Alarm"
        } else if self.check {
            "Check"
        } else if self.holding {
            "Hold:0"
        } else if self.jogging() {
            "Jog"
        } else if self.moving() {
            "Run"
        } else {
            "Idle"
        }
    }

    /// Whether the only motion is a jog.
    fn jogging(&self) -> bool {
        !self.planner.is_empty()
            && self
                .planner
                .iter()
                .all(|b| matches!(b.kind, BlockKind::Jog { .. }))
    }

    fn status_report(&mut self) -> String {
        let p = self.position();
        let feed = match self.planner.front() {
            Some(
                b @ Block {
                    kind: BlockKind::Motion(_) | BlockKind::Jog { .. },
                    ..
                },
            ) if self.moving() && b.started => b.v * 60.0,
            _ => 0.0,
        };
        let mut s = format!(
            "<{}|MPos:{:.3},{:.3},{:.3}|Bf:{},{}|FS:{:.0},{:.0}",
            self.state_word(),
            p[0],
            p[1],
            p[2],
            self.cfg.planner_blocks.saturating_sub(self.planner.len()),
            self.cfg.rx_buffer.saturating_sub(self.rx.len()),
            feed,
            if self.interp.modal.spindle == 5 {
                0.0
            } else {
                self.interp.modal.spindle_speed
            }
        );
        if self.reports.is_multiple_of(10) {
            let w = self.interp.wco();
            s.push_str(&format!("|WCO:{:.3},{:.3},{:.3}", w[0], w[1], w[2]));
        } else if self.reports % 10 == 1 {
            let o = self.overrides;
            s.push_str(&format!("|Ov:{},{},{}", o[0], o[1], o[2]));
        }
        self.reports += 1;
        s.push('>');
        s
    }

    /// One byte arrives on the wire: real-time commands act at once (as GRBL's serial
    /// interrupt does), other bytes go to the receive buffer or are dropped when it is full.
    pub fn receive(&mut self, b: u8, now: Instant) {
        if self.silent(now) {
            self.lost_while_silent += 1;
            return;
        }
        match b {
            b'?' => {
                self.advance(now);
                let r = self.status_report();
                self.say(&r);
            }
            b'!' => {
                self.advance(now);
                if self.jogging() {
                    // a feed hold during a jog cancels the jog
                    self.cancel_jog();
                } else if self.alarm.is_none() && !self.check {
                    self.holding = true;
                }
            }
            0x85 => {
                self.advance(now);
                self.cancel_jog();
            }
            b'~' => {
                self.advance(now);
                if self.holding && self.alarm.is_none() {
                    self.holding = false;
                }
            }
            0x18 => self.reset(now),
            0x90 => self.overrides[0] = 100,
            0x91 => self.overrides[0] = (self.overrides[0] + 10).min(200),
            0x92 => self.overrides[0] = self.overrides[0].saturating_sub(10).max(10),
            0x93 => self.overrides[0] = (self.overrides[0] + 1).min(200),
            0x94 => self.overrides[0] = self.overrides[0].saturating_sub(1).max(10),
            0x95 => self.overrides[1] = 100,
            0x96 => self.overrides[1] = 50,
            0x97 => self.overrides[1] = 25,
            0x99 => self.overrides[2] = 100,
            0x9A => self.overrides[2] = (self.overrides[2] + 10).min(200),
            0x9B => self.overrides[2] = self.overrides[2].saturating_sub(10).max(10),
            0x9C => self.overrides[2] = (self.overrides[2] + 1).min(200),
            0x9D => self.overrides[2] = self.overrides[2].saturating_sub(1).max(10),
            b if b >= 0x80 => {}
            b => {
                if self.cfg.rx_buffer <= self.rx.len() {
                    self.overflows += 1;
                } else {
                    self.rx.push_back(b);
                }
            }
        }
    }

    fn reset(&mut self, now: Instant) {
        self.advance(now);
        if self.moving() && self.alarm.is_none() && !self.check {
            self.alarm = Some(3);
            self.say("ALARM:3");
        }
        self.pos = self.position();
        self.interp.pos = self.pos;
        self.interp.reset_modal();
        self.rx.clear();
        self.line.clear();
        self.raw.clear();
        self.line_overflow = false;
        self.in_comment = false;
        self.waiting.clear();
        self.planner.clear();
        self.holding = false;
        self.homing = false;
        self.critical = false;
        self.check = false;
        self.overrides = [100, 100, 100];
        self.out.extend_from_slice(BANNER.as_bytes());
        if self.alarm.is_some() {
            self.say("[MSG:'$H'|'$X' to unlock]");
        }
    }

    fn raise_alarm(&mut self, code: u8) {
        self.pos = self.position();
        self.interp.pos = self.pos;
        self.planner.clear();
        self.waiting.clear();
        self.alarm = Some(code);
        self.critical = true;
        self.say(&format!("ALARM:{code}"));
        self.say("[MSG:Reset to continue]");
    }

    /// Stops a jog where the tool is and drops the jog blocks still planned.
    fn cancel_jog(&mut self) {
        if !self.jogging() {
            return;
        }
        let at = self.position();
        self.planner.clear();
        self.pos = at;
        self.interp.pos = at;
        self.events.push(super::TraceEvent::Jogged { to: at });
    }

    /// Runs the main loop until it has to wait: parses buffered lines, plans their
    /// blocks while the planner has room, acknowledges them.
    pub fn process(&mut self, now: Instant) {
        self.advance(now);
        loop {
            if self.critical || self.homing || self.silent(now) {
                return;
            }
            if !self.waiting.is_empty() {
                while self.planner.len() < self.cfg.planner_blocks {
                    let Some(b) = self.waiting.pop_front() else {
                        break;
                    };
                    self.planner.push_back(b);
                    // the new block may finish at once (instant machines, empty moves)
                    self.advance(now);
                }
                if !self.waiting.is_empty() {
                    return;
                }
                self.say("ok");
                continue;
            }
            // GRBL's protocol loop: take characters from the receive buffer up to a line end
            let mut complete = false;
            while let Some(c) = self.rx.pop_front() {
                if c == b'\n' || c == b'\r' {
                    complete = true;
                    break;
                }
                self.raw.push(c);
                if self.in_comment {
                    if c == b')' {
                        self.in_comment = false;
                    }
                    continue;
                }
                if c <= b' ' {
                    continue;
                }
                if c == b'(' {
                    self.in_comment = true;
                    continue;
                }
                if self.line.len() >= LINE_BUFFER - 1 {
                    self.line_overflow = true;
                } else {
                    self.line.push(c.to_ascii_uppercase());
                }
            }
            if !complete {
                return;
            }
            let raw = String::from_utf8_lossy(&std::mem::take(&mut self.line)).into_owned();
            let received = String::from_utf8_lossy(&std::mem::take(&mut self.raw)).into_owned();
            self.in_comment = false;
            if !raw.is_empty() && !raw.starts_with('$') {
                if let Some(seconds) = self.hang_due() {
                    // the main loop hangs on this line: it and what follows are lost
                    self.silent_until = Some(now + Duration::from_secs_f64(seconds.max(0.0)));
                    self.lost_while_silent += (received.len() + 1 + self.rx.len()) as u64;
                    self.rx.clear();
                    self.line_overflow = false;
                    // once: awake again, the controller takes lines as before
                    self.cfg
                        .faults
                        .retain(|f| !matches!(f, GrblFault::SilentAfterLine { .. }));
                    return;
                }
            }
            if !raw.is_empty() {
                let n = (!raw.starts_with('$')).then_some(self.received + 1);
                self.events
                    .push(super::TraceEvent::Received { n, line: received });
            }
            if std::mem::take(&mut self.line_overflow) {
                self.say("error:11");
                continue;
            }
            self.execute_line(&raw, now);
        }
    }

    fn execute_line(&mut self, raw: &str, now: Instant) {
        let line = clean_line(raw);
        if line.is_empty() {
            self.say("ok");
            return;
        }
        if line.starts_with('$') {
            self.system_command(&line, now);
            return;
        }
        self.received += 1;
        let n = self.received;
        for f in self.cfg.faults.clone() {
            match f {
                GrblFault::ErrorAtLine { line: l, code } if l == n => {
                    self.say(&format!("error:{code}"));
                    return;
                }
                GrblFault::AlarmAtLine { line: l, code } if l == n => {
                    self.raise_alarm(code);
                    return;
                }
                _ => {}
            }
        }
        if self.alarm.is_some() {
            self.say("error:9");
            return;
        }
        let actions = match self.interp.execute(&line) {
            Ok(a) => a,
            Err(code) => {
                self.say(&format!("error:{code}"));
                return;
            }
        };
        if self.check {
            self.say("ok");
            return;
        }
        for a in actions {
            let block = match a {
                Action::Move {
                    motion,
                    from,
                    to,
                    center,
                    feed,
                } => {
                    let rapid = motion == Motion::Rapid;
                    let f = if rapid { self.cfg.rapid_feed } else { feed };
                    let length = path_length(motion, from, to, center);
                    Block {
                        kind: BlockKind::Motion(Executed {
                            index: n,
                            line: raw.to_string(),
                            motion,
                            from,
                            to,
                            center,
                            feed: f,
                        }),
                        duration: 0.0,
                        elapsed: 0.0,
                        length,
                        v: 0.0,
                        a: self.cfg.accel.max(1e-6),
                        feed: f,
                        rapid,
                        started: false,
                    }
                }
                Action::Dwell(p) => Block {
                    kind: BlockKind::Dwell,
                    duration: p,
                    elapsed: 0.0,
                    length: 0.0,
                    v: 1.0,
                    a: 1.0,
                    feed: 0.0,
                    rapid: false,
                    started: false,
                },
                Action::Pause => Block {
                    kind: BlockKind::Pause,
                    duration: 0.0,
                    elapsed: 0.0,
                    length: 0.0,
                    v: 1.0,
                    a: 1.0,
                    feed: 0.0,
                    rapid: false,
                    started: false,
                },
                Action::ProgramEnd => continue,
            };
            self.waiting.push_back(block);
        }
        if self.waiting.is_empty() {
            self.say("ok");
        }
        // otherwise `process` plans the blocks and says ok once they are all in
    }

    fn system_command(&mut self, line: &str, now: Instant) {
        let busy = self.moving() || self.holding;
        match line {
            "$" => {
                self.say("[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]");
                self.say("ok");
            }
            "$I" => {
                self.say("[VER:1.1h.20190825:]");
                let opt = format!("[OPT:V,{},{}]", self.cfg.planner_blocks, self.cfg.rx_buffer);
                self.say(&opt);
                self.say("ok");
            }
            "$$" if busy => self.say("error:8"),
            "$$" => {
                let lines: Vec<String> = self
                    .settings
                    .iter()
                    .map(|(k, v)| format!("${k}={v}"))
                    .collect();
                for l in lines {
                    self.say(&l);
                }
                self.say("ok");
            }
            "$G" => {
                let m = &self.interp.modal;
                let motion = match m.motion {
                    Some(Motion::Rapid) => "G0",
                    Some(Motion::Linear) => "G1",
                    Some(Motion::ArcCw) => "G2",
                    Some(Motion::ArcCcw) => "G3",
                    None => "G80",
                };
                let s = format!(
                    "[GC:{motion} G{} G{} {} {} G94 M{} M9 T{} F{} S{}]",
                    54 + m.wcs,
                    m.plane,
                    if m.inches { "G20" } else { "G21" },
                    if m.relative { "G91" } else { "G90" },
                    m.spindle,
                    m.tool,
                    m.feed,
                    m.spindle_speed
                );
                self.say(&s);
                self.say("ok");
            }
            "$#" => {
                let o = self.interp.offsets;
                for (k, w) in o.iter().enumerate() {
                    self.say(&format!(
                        "[G{}:{:.3},{:.3},{:.3}]",
                        54 + k,
                        w[0],
                        w[1],
                        w[2]
                    ));
                }
                for g in ["G28", "G30", "G92"] {
                    self.say(&format!("[{g}:0.000,0.000,0.000]"));
                }
                self.say("[TLO:0.000]");
                self.say("[PRB:0.000,0.000,0.000:0]");
                self.say("ok");
            }
            "$N" => {
                self.say("$N0=");
                self.say("$N1=");
                self.say("ok");
            }
            "$X" => {
                if self.alarm.take().is_some() {
                    self.critical = false;
                    self.say("[MSG:Caution: Unlocked]");
                }
                self.events.push(super::TraceEvent::Unlocked);
                self.say("ok");
            }
            "$H" if !self.cfg.homing => self.say("error:5"),
            "$H" if busy => self.say("error:8"),
            "$H" => {
                // the cycle runs to the machine's zero; its ok comes when it is over
                let from = self.position();
                let length = from.iter().map(|v| v * v).sum::<f64>().sqrt();
                let feed = self
                    .settings
                    .get(&25)
                    .and_then(|v| v.parse::<f64>().ok())
                    .unwrap_or(500.0);
                self.alarm = None;
                self.critical = false;
                self.homing = true;
                self.planner.push_back(Block {
                    kind: BlockKind::Home { from },
                    duration: 0.0,
                    elapsed: 0.0,
                    length,
                    v: 0.0,
                    a: self.cfg.accel.max(1e-6),
                    feed,
                    rapid: false,
                    started: false,
                });
                self.advance(now);
            }
            l if l.starts_with("$J=") => self.jog(&l[3..], now),
            "$C" if self.check => {
                self.say("[MSG:Disabled]");
                self.say("ok");
                self.reset(now);
            }
            "$C" if busy || self.alarm.is_some() => self.say("error:8"),
            "$C" => {
                self.check = true;
                self.say("[MSG:Enabled]");
                self.say("ok");
            }
            l if l.starts_with("$RST=") => self.say("ok"),
            l => {
                let Some((k, v)) = l[1..].split_once('=') else {
                    self.say("error:3");
                    return;
                };
                let Ok(k) = k.parse::<u16>() else {
                    self.say("error:3");
                    return;
                };
                if !self.settings.contains_key(&k) {
                    self.say("error:3");
                    return;
                }
                if busy {
                    self.say("error:8");
                    return;
                }
                match v.parse::<f64>() {
                    Err(_) => self.say("error:2"),
                    Ok(x) if x < 0.0 => self.say("error:4"),
                    Ok(_) => {
                        self.settings.insert(k, v.to_string());
                        self.say("ok");
                    }
                }
            }
        }
    }
}

impl Machine {
    /// `$J=…`: a jog in work or machine coordinates, distances absolute or relative, with
    /// its own feed; only while idle (or jogging), never in alarm.
    fn jog(&mut self, words: &str, now: Instant) {
        let idle = self
            .planner
            .iter()
            .all(|b| matches!(b.kind, BlockKind::Jog { .. }))
            && self.waiting.is_empty()
            && !self.holding;
        if self.alarm.is_some() || self.check || !idle {
            self.say("error:8");
            return;
        }
        let mut relative = self.interp.modal.relative;
        let mut scale = if self.interp.modal.inches { 25.4 } else { 1.0 };
        let mut machine = false;
        let mut feed = None;
        let mut axis = [None; 3];
        let b = words.as_bytes();
        let mut i = 0;
        while i < b.len() {
            let letter = b[i];
            i += 1;
            let start = i;
            while i < b.len()
                && (b[i].is_ascii_digit() || b[i] == b'.' || b[i] == b'-' || b[i] == b'+')
            {
                i += 1;
            }
            let Some(v) = std::str::from_utf8(&b[start..i])
                .ok()
                .and_then(|t| t.parse::<f64>().ok())
            else {
                self.say("error:2");
                return;
            };
            match (letter, (v * 10.0).round() as i64) {
                (b'G', 900) => relative = false,
                (b'G', 910) => relative = true,
                (b'G', 200) => scale = 25.4,
                (b'G', 210) => scale = 1.0,
                (b'G', 530) => machine = true,
                (b'X', _) => axis[0] = Some(v),
                (b'Y', _) => axis[1] = Some(v),
                (b'Z', _) => axis[2] = Some(v),
                (b'F', _) => feed = Some(v * scale),
                _ => {
                    self.say("error:20");
                    return;
                }
            }
        }
        let Some(feed) = feed.filter(|f| *f > 0.0) else {
            self.say("error:22");
            return;
        };
        if axis.iter().all(Option::is_none) {
            self.say("error:26");
            return;
        }
        let from = self.position();
        let wco = self.interp.wco();
        let mut to = from;
        for k in 0..3 {
            if let Some(v) = axis[k] {
                to[k] = if relative {
                    from[k] + v * scale
                } else if machine {
                    v * scale
                } else {
                    v * scale + wco[k]
                };
            }
        }
        let length = (0..3)
            .map(|k| (to[k] - from[k]).powi(2))
            .sum::<f64>()
            .sqrt();
        self.planner.push_back(Block {
            kind: BlockKind::Jog { from, to },
            duration: 0.0,
            elapsed: 0.0,
            length,
            v: 0.0,
            a: self.cfg.accel.max(1e-6),
            feed: feed.min(self.cfg.max_feed),
            rapid: false,
            started: false,
        });
        self.interp.pos = to;
        self.advance(now);
        self.say("ok");
    }
}

/// Signed sweep (radians) of the XY arc from `from` to `to` about `c`; a full turn when
/// the ends coincide, as GRBL reads `G2`/`G3` with the target at the start.
pub fn arc_sweep(from: [f64; 3], to: [f64; 3], c: [f64; 2], ccw: bool) -> f64 {
    let a0 = (from[1] - c[1]).atan2(from[0] - c[0]);
    let a1 = (to[1] - c[1]).atan2(to[0] - c[0]);
    let mut s = a1 - a0;
    let tau = std::f64::consts::TAU;
    if ccw {
        while s <= 1e-9 {
            s += tau;
        }
    } else {
        while s >= -1e-9 {
            s -= tau;
        }
    }
    s
}

fn path_length(m: Motion, from: [f64; 3], to: [f64; 3], center: Option<[f64; 2]>) -> f64 {
    match (m, center) {
        (Motion::ArcCw | Motion::ArcCcw, Some(c)) => {
            let r = (from[0] - c[0]).hypot(from[1] - c[1]);
            let xy = r * arc_sweep(from, to, c, m == Motion::ArcCcw).abs();
            xy.hypot(to[2] - from[2])
        }
        _ => ((to[0] - from[0]).powi(2) + (to[1] - from[1]).powi(2) + (to[2] - from[2]).powi(2))
            .sqrt(),
    }
}

/// Duration (s) and peak speed (mm/s) of a move of `l` mm that starts and ends at rest.
fn trapezoid(l: f64, v: f64, a: f64) -> (f64, f64) {
    if l <= 0.0 {
        return (0.0, v);
    }
    if l >= v * v / a {
        (l / v + v / a, v)
    } else {
        let t = (l / a).sqrt();
        (2.0 * t, a * t)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    fn feed(m: &mut Machine, s: &str, now: Instant) {
        for b in s.bytes() {
            m.receive(b, now);
        }
        m.process(now);
    }

    fn said(m: &mut Machine) -> String {
        String::from_utf8(m.take_output()).unwrap()
    }

    #[test]
    fn a_full_receive_buffer_drops_and_counts_bytes() {
        let t0 = Instant::now();
        let mut m = Machine::new(GrblSimConfig::default(), t0);
        said(&mut m);
        // nothing is processed while bytes arrive: 200 bytes into 128
        for b in "G1 X1 F100\n".repeat(20).bytes() {
            m.receive(b, t0);
        }
        assert_eq!(m.overflows, 220 - 128);
        // the real-time bytes still get through a full buffer
        m.receive(b'?', t0);
        assert!(said(&mut m).starts_with("<Idle|MPos:0.000,0.000,0.000|Bf:15,0|"));
    }

    #[test]
    fn ok_waits_for_planner_room_and_motion_takes_simulated_time() {
        let t0 = Instant::now();
        let cfg = GrblSimConfig {
            planner_blocks: 2,
            ..Default::default()
        };
        let mut m = Machine::new(cfg, t0);
        said(&mut m);
        feed(&mut m, "G1 X10 F600\nG1 X20\nG1 X30\n", t0);
        // two blocks fit, the third line waits for room: two oks
        assert_eq!(said(&mut m), "ok\r\nok\r\n");
        m.receive(b'?', t0);
        assert!(said(&mut m).starts_with("<Run|"));
        // 10 mm at 10 mm/s with 500 mm/s² takes 1.02 s; after 1.1 s the first is done
        m.process(t0 + Duration::from_millis(1100));
        assert_eq!(said(&mut m), "ok\r\n");
        assert_eq!(m.trace.len(), 1);
        m.process(t0 + Duration::from_secs(10));
        assert_eq!(m.trace.len(), 3);
        assert!(
            (m.motion_time - 3.0 * 1.02).abs() < 1e-9,
            "{}",
            m.motion_time
        );
        m.receive(b'?', t0 + Duration::from_secs(10));
        assert!(said(&mut m).starts_with("<Idle|MPos:30.000,0.000,0.000|Bf:2,128|"));
    }

    #[test]
    fn hold_resume_and_reset_in_motion_raises_alarm_3() {
        let t0 = Instant::now();
        let mut m = Machine::new(GrblSimConfig::default(), t0);
        said(&mut m);
        feed(&mut m, "G1 X10 F600\n", t0);
        m.receive(b'!', t0 + Duration::from_millis(500));
        let p = m.position();
        m.process(t0 + Duration::from_secs(5));
        assert_eq!(m.position(), p, "a held machine does not move");
        m.receive(b'?', t0 + Duration::from_secs(5));
        assert!(said(&mut m).contains("<Hold:0|"));
        m.receive(b'~', t0 + Duration::from_secs(5));
        m.receive(0x18, t0 + Duration::from_millis(5200));
        let out = said(&mut m);
        assert!(
            out.contains("ALARM:3") && out.contains("Grbl 1.1h"),
            "{out}"
        );
        feed(&mut m, "G0 X0\n", t0 + Duration::from_secs(6));
        assert_eq!(said(&mut m), "error:9\r\n");
        feed(&mut m, "$X\nG0 X0\n", t0 + Duration::from_secs(6));
        assert_eq!(said(&mut m), "[MSG:Caution: Unlocked]\r\nok\r\nok\r\n");
    }

    #[test]
    fn check_mode_parses_without_moving_and_leaving_it_resets() {
        let t0 = Instant::now();
        let mut m = Machine::new(GrblSimConfig::default(), t0);
        said(&mut m);
        feed(&mut m, "$C\nG1 X5 F100\nG2 X9 Y0 I1 J0\n$C\n", t0);
        let out = said(&mut m);
        assert_eq!(
            out,
            "[MSG:Enabled]\r\nok\r\nok\r\nerror:33\r\n[MSG:Disabled]\r\nok\r\n\r\nGrbl 1.1h ['$' for help]\r\n"
        );
        m.process(t0 + Duration::from_secs(10));
        assert!(m.trace.is_empty());
        assert_eq!(m.received, 2);
    }

    #[test]
    fn settings_and_line_overflow() {
        let t0 = Instant::now();
        let mut m = Machine::new(GrblSimConfig::default(), t0);
        said(&mut m);
        feed(&mut m, "$110=800\n$999=1\n$110=abc\n", t0);
        assert_eq!(said(&mut m), "ok\r\nerror:3\r\nerror:2\r\n");
        feed(&mut m, &format!("G1X{}\n", "1".repeat(90)), t0);
        assert_eq!(said(&mut m), "error:11\r\n");
        feed(&mut m, "$$\n", t0);
        assert!(said(&mut m).contains("$110=800\r\n"));
    }
}
