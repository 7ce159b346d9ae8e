//! The simulated GRBL's G-code interpreter: GRBL 1.1's block rules, modal state and checks.
//!
//! It takes one line as GRBL's protocol layer hands it over (spaces and comments removed,
//! letters upper-cased, see [`clean_line`]) and either returns the actions it asks for or
//! the `error:N` code GRBL 1.1 would answer. Tests also use it as a G-code reader.

use serde::{Deserialize, Serialize};

/// The kind of a motion line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Motion {
    Rapid,
    Linear,
    ArcCw,
    ArcCcw,
}

/// What one line asks the machine to do, in order.
#[derive(Clone, Debug, PartialEq)]
pub enum Action {
    Move {
        motion: Motion,
        from: [f64; 3],
        to: [f64; 3],
        /// The arc's centre (absolute XY) for arcs.
        center: Option<[f64; 2]>,
        /// mm/min (0 for rapids: the machine's rapid rate applies).
        feed: f64,
    },
    Dwell(f64),
    /// M0/M1: stop and wait for cycle start.
    Pause,
    /// M2/M30.
    ProgramEnd,
}

/// The modal state GRBL keeps between lines.
#[derive(Clone, Debug, PartialEq)]
pub struct Modal {
    /// None after G80.
    pub motion: Option<Motion>,
    pub inches: bool,
    pub relative: bool,
    /// 17, 18 or 19.
    pub plane: u8,
    /// mm/min; 0 until an F word is seen.
    pub feed: f64,
    pub spindle_speed: f64,
    /// 3, 4 or 5.
    pub spindle: u8,
    pub tool: u32,
    /// The work coordinate system in force: 0 for G54 … 5 for G59.
    pub wcs: usize,
}

impl Default for Modal {
    fn default() -> Self {
        Modal {
            motion: Some(Motion::Rapid),
            inches: false,
            relative: false,
            plane: 17,
            feed: 0.0,
            spindle_speed: 0.0,
            spindle: 5,
            tool: 0,
            wcs: 0,
        }
    }
}

/// A G-code interpreter with GRBL 1.1's rules.
#[derive(Clone, Debug, Default)]
pub struct Interpreter {
    pub modal: Modal,
    /// The position the parser believes the machine is at, in machine coordinates, mm.
    pub pos: [f64; 3],
    /// The work offsets of G54 … G59 (machine position of each work zero), mm; kept
    /// through a reset, as GRBL keeps them in EEPROM.
    pub offsets: [[f64; 3]; 6],
    /// The machine Z at which a tool going down touches the touch plate (G38.2 stops
    /// there); None: there is no plate, and a probe is error 20 here (GRBL would alarm).
    pub touch_plate_z: Option<f64>,
    /// The positions `G28` and `G30` go to (machine coordinates, mm), stored by `G28.1` and
    /// `G30.1`; GRBL keeps them in EEPROM, zero until stored.
    pub stored: [[f64; 3]; 2],
    /// `M6` is taken, as by a grblHAL with a manual tool changer: the controller holds there
    /// (as at `M0`) until cycle start. Off (GRBL 1.1): `M6` is error 20.
    pub m6_holds: bool,
}

/// GRBL's line cleaning: drops spaces, control characters and comments (`(…)` and `;…`),
/// upper-cases letters.
pub fn clean_line(raw: &str) -> String {
    let mut out = String::new();
    let mut in_paren = false;
    for c in raw.chars() {
        if in_paren {
            in_paren = c != ')';
            continue;
        }
        match c {
            '(' => in_paren = true,
            ';' => break,
            c if c <= ' ' => {}
            c => out.push(c.to_ascii_uppercase()),
        }
    }
    out
}

/// GRBL's `read_float`: optional sign, digits with at most one point, no exponent.
fn read_number(s: &[u8], i: &mut usize) -> Option<f64> {
    let start = *i;
    if *i < s.len() && (s[*i] == b'-' || s[*i] == b'+') {
        *i += 1;
    }
    let mut digits = 0;
    let mut point = false;
    while *i < s.len() {
        match s[*i] {
            b'0'..=b'9' => digits += 1,
            b'.' if !point => point = true,
            _ => break,
        }
        *i += 1;
    }
    if digits == 0 {
        return None;
    }
    std::str::from_utf8(&s[start..*i]).ok()?.parse().ok()
}

/// GRBL 1.1's arc check on an I/J arc (in single precision, as on the controller):
/// false when the target is not on the circle within 0.005 mm or 0.1 % of the radius.
pub fn arc_target_ok(from: [f64; 2], to: [f64; 2], ij: [f64; 2]) -> bool {
    let x = (to[0] - from[0]) as f32 - ij[0] as f32;
    let y = (to[1] - from[1]) as f32 - ij[1] as f32;
    let target_r = x.hypot(y);
    let r = (ij[0] as f32).hypot(ij[1] as f32);
    let delta_r = (target_r - r).abs();
    if delta_r > 0.005 {
        if delta_r > 0.5 {
            return false;
        }
        if delta_r > 0.001 * r {
            return false;
        }
    }
    true
}

const SUPPORTED_LETTERS: &[u8] = b"FGIJKLMNPRSTXYZ";

impl Interpreter {
    pub fn new() -> Self {
        Self::default()
    }

    /// What a soft reset does to the parser: modal state back to defaults, position kept.
    pub fn reset_modal(&mut self) {
        self.modal = Modal::default();
    }

    /// The work offset in force (machine position of the work zero).
    pub fn wco(&self) -> [f64; 3] {
        self.offsets[self.modal.wcs]
    }

    /// Runs one cleaned line (see [`clean_line`]); Err is GRBL's error code.
    pub fn execute(&mut self, line: &str) -> Result<Vec<Action>, u8> {
        let s = line.as_bytes();
        let mut i = 0;
        let mut words: Vec<(u8, f64)> = Vec::new();
        while i < s.len() {
            let letter = s[i];
            if !letter.is_ascii_uppercase() {
                return Err(1);
            }
            i += 1;
            let Some(v) = read_number(s, &mut i) else {
                return Err(2);
            };
            if !SUPPORTED_LETTERS.contains(&letter) {
                return Err(20);
            }
            words.push((letter, v));
        }

        let mut motion_cmd: Option<Option<Motion>> = None;
        // G38.2: a feed move down that stops where the tool touches the plate
        let mut probe = false;
        let mut dwell = false;
        let mut g53 = false;
        let mut g10 = false;
        // G28/G30: to a stored position (0, 1), via the axis words' intermediate point;
        // G28.1/G30.1: store the position
        let mut go_stored: Option<usize> = None;
        let mut store: Option<usize> = None;
        let mut tool_stop = false;
        let mut wcs: Option<usize> = None;
        let mut units: Option<bool> = None;
        let mut distance: Option<bool> = None;
        let mut plane: Option<u8> = None;
        let mut spindle: Option<u8> = None;
        let mut stop: Option<Action> = None;
        let mut seen_groups: Vec<&str> = Vec::new();
        let mut value: [Option<f64>; 26] = [None; 26];
        let mut group = |g: &'static str| -> Result<(), u8> {
            if seen_groups.contains(&g) {
                Err(21)
            } else {
                seen_groups.push(g);
                Ok(())
            }
        };
        for &(letter, v) in &words {
            match letter {
                b'G' => {
                    let code10 = (v * 10.0).round();
                    if (code10 - v * 10.0).abs() > 1e-6 {
                        return Err(20);
                    }
                    match code10 as i64 {
                        0 | 10 | 20 | 30 | 800 => {
                            group("motion")?;
                            motion_cmd = Some(match code10 as i64 {
                                0 => Some(Motion::Rapid),
                                10 => Some(Motion::Linear),
                                20 => Some(Motion::ArcCw),
                                30 => Some(Motion::ArcCcw),
                                _ => None,
                            });
                        }
                        40 => {
                            group("non-modal")?;
                            dwell = true;
                        }
                        382 => {
                            group("motion")?;
                            probe = true;
                        }
                        530 => {
                            group("non-modal")?;
                            g53 = true;
                        }
                        170 | 180 | 190 => {
                            group("plane")?;
                            plane = Some((code10 / 10.0) as u8);
                        }
                        200 | 210 => {
                            group("units")?;
                            units = Some(code10 as i64 == 200);
                        }
                        900 | 910 => {
                            group("distance")?;
                            distance = Some(code10 as i64 == 910);
                        }
                        940 => group("feed mode")?,
                        540 | 550 | 560 | 570 | 580 | 590 => {
                            group("coordinate system")?;
                            wcs = Some((code10 as usize - 540) / 10);
                        }
                        100 => {
                            group("non-modal")?;
                            g10 = true;
                        }
                        280 | 300 => {
                            group("non-modal")?;
                            go_stored = Some(usize::from(code10 as i64 == 300));
                        }
                        281 | 301 => {
                            group("non-modal")?;
                            store = Some(usize::from(code10 as i64 == 301));
                        }
                        911 => group("arc distance")?,
                        490 => group("tool length")?,
                        _ => return Err(20),
                    }
                }
                b'M' => {
                    if v.fract() != 0.0 {
                        return Err(20);
                    }
                    match v as i64 {
                        0 | 1 | 2 | 30 => {
                            group("stopping")?;
                            stop = Some(if v < 2.0 {
                                Action::Pause
                            } else {
                                Action::ProgramEnd
                            });
                        }
                        3..=5 => {
                            group("spindle")?;
                            spindle = Some(v as u8);
                        }
                        7..=9 => group("coolant")?,
                        6 if self.m6_holds => {
                            group("tool change")?;
                            tool_stop = true;
                        }
                        _ => return Err(20),
                    }
                }
                l => {
                    let slot = &mut value[(l - b'A') as usize];
                    if slot.is_some() {
                        return Err(25);
                    }
                    *slot = Some(v);
                }
            }
        }
        let val = |l: u8| value[(l - b'A') as usize];
        for l in [b'F', b'N', b'P', b'S', b'T'] {
            if val(l).is_some_and(|v| v < 0.0) {
                return Err(4);
            }
        }
        if val(b'T').is_some_and(|t| t > 255.0) {
            return Err(38);
        }
        if val(b'L').is_some() && !g10 {
            return Err(20);
        }
        if g10 {
            // G10 L2 Pn / G10 L20 Pn: set a work offset (n 1 to 6 for G54 to G59, 0: the one
            // in force); nothing moves
            let (Some(l), Some(p)) = (val(b'L'), val(b'P')) else {
                return Err(36);
            };
            if p.fract() != 0.0 || !(0.0..=6.0).contains(&p) {
                return Err(29);
            }
            let n = if p == 0.0 {
                self.modal.wcs
            } else {
                p as usize - 1
            };
            let scale = if units.unwrap_or(self.modal.inches) {
                25.4
            } else {
                1.0
            };
            for (k, l_axis) in [b'X', b'Y', b'Z'].into_iter().enumerate() {
                if let Some(v) = val(l_axis) {
                    self.offsets[n][k] = match l as i64 {
                        2 => v * scale,
                        20 => self.pos[k] - v * scale,
                        _ => return Err(20),
                    };
                }
            }
            return Ok(Vec::new());
        }
        if let Some(w) = wcs {
            self.modal.wcs = w;
        }

        // modal changes in GRBL's order of execution
        let scale = if units.unwrap_or(self.modal.inches) {
            25.4
        } else {
            1.0
        };
        if let Some(f) = val(b'F') {
            self.modal.feed = f * scale;
        }
        if let Some(s) = val(b'S') {
            self.modal.spindle_speed = s;
        }
        if let Some(t) = val(b'T') {
            self.modal.tool = t as u32;
        }
        if let Some(sp) = spindle {
            self.modal.spindle = sp;
        }
        let mut actions = Vec::new();
        if dwell {
            let Some(p) = val(b'P') else {
                return Err(28);
            };
            actions.push(Action::Dwell(p));
        } else if val(b'P').is_some() {
            return Err(36);
        }
        if let Some(p) = plane {
            self.modal.plane = p;
        }
        if let Some(u) = units {
            self.modal.inches = u;
        }
        if let Some(d) = distance {
            self.modal.relative = d;
        }
        if let Some(m) = motion_cmd {
            self.modal.motion = m;
        }
        if tool_stop {
            // the tool change comes before the line's motion; the machine holds for it
            actions.push(Action::Pause);
        }

        let axis = [val(b'X'), val(b'Y'), val(b'Z')];
        let has_axis = axis.iter().any(Option::is_some);
        let offsets = [val(b'I'), val(b'J'), val(b'K')];
        let has_offsets = offsets.iter().any(Option::is_some) || val(b'R').is_some();
        if probe {
            // G38.2 Z…: straight down at the feed until the tool touches the plate (the
            // simulator probes along Z only, as machlink's posts write it)
            let Some(contact) = self.touch_plate_z else {
                return Err(20);
            };
            if self.modal.feed <= 0.0 {
                return Err(22);
            }
            let (Some(z), None, None) = (axis[2], axis[0], axis[1]) else {
                return Err(20);
            };
            let from = self.pos;
            let target = if self.modal.relative {
                from[2] + z * scale
            } else {
                z * scale + self.wco()[2]
            };
            if target > contact || from[2] < contact {
                // it would never touch: GRBL raises ALARM:5 (probe fail)
                return Err(20);
            }
            let to = [from[0], from[1], contact];
            self.pos = to;
            actions.push(Action::Move {
                motion: Motion::Linear,
                from,
                to,
                center: None,
                feed: self.modal.feed,
            });
            return Ok(actions);
        }
        if let Some(k) = store {
            if has_axis {
                return Err(20);
            }
            self.stored[k] = self.pos;
            return Ok(actions);
        }
        if let Some(k) = go_stored {
            // GRBL 1.1: with axis words, a rapid to the point they name (in the distance
            // mode and work offset in force), then those axes alone to the stored
            // position; without, every axis to it
            if has_offsets || motion_cmd.is_some() {
                return Err(if has_offsets { 36 } else { 21 });
            }
            let from = self.pos;
            let mut via = from;
            let mut to = self.stored[k];
            let wco = self.wco();
            if has_axis {
                for k in 0..3 {
                    match axis[k] {
                        Some(v) if self.modal.relative => via[k] = from[k] + v * scale,
                        Some(v) => via[k] = v * scale + wco[k],
                        None => to[k] = from[k],
                    }
                }
                actions.push(Action::Move {
                    motion: Motion::Rapid,
                    from,
                    to: via,
                    center: None,
                    feed: 0.0,
                });
            }
            actions.push(Action::Move {
                motion: Motion::Rapid,
                from: via,
                to,
                center: None,
                feed: 0.0,
            });
            self.pos = to;
            if let Some(s) = stop {
                actions.push(s);
            }
            return Ok(actions);
        }
        let motion = self.modal.motion;
        if g53 && !matches!(motion, Some(Motion::Rapid | Motion::Linear)) {
            return Err(30);
        }
        match motion {
            None => {
                if has_axis {
                    return Err(31);
                }
                if has_offsets {
                    return Err(36);
                }
            }
            Some(m) if has_axis => {
                let from = self.pos;
                let mut to = from;
                let wco = self.wco();
                for k in 0..3 {
                    if let Some(v) = axis[k] {
                        to[k] = if g53 {
                            v * scale
                        } else if self.modal.relative {
                            from[k] + v * scale
                        } else {
                            v * scale + wco[k]
                        };
                    }
                }
                let feed = if m == Motion::Rapid {
                    0.0
                } else {
                    if self.modal.feed <= 0.0 {
                        return Err(22);
                    }
                    self.modal.feed
                };
                let center = match m {
                    Motion::Rapid | Motion::Linear => {
                        if has_offsets {
                            return Err(36);
                        }
                        None
                    }
                    Motion::ArcCw | Motion::ArcCcw => {
                        if self.modal.plane != 17 {
                            // the simulator only knows arcs in the XY plane
                            return Err(20);
                        }
                        if axis[0].is_none() && axis[1].is_none() {
                            return Err(32);
                        }
                        Some(self.arc_center(m, from, to, &offsets, val(b'R'), scale)?)
                    }
                };
                self.pos = to;
                actions.push(Action::Move {
                    motion: m,
                    from,
                    to,
                    center,
                    feed,
                });
            }
            Some(m) => {
                if motion_cmd.is_some() && matches!(m, Motion::ArcCw | Motion::ArcCcw) {
                    return Err(26);
                }
                if has_offsets {
                    return Err(36);
                }
            }
        }
        if let Some(s) = stop {
            if s == Action::ProgramEnd {
                // GRBL's program end: back to G1 G17 G90 G94 G54, spindle off
                self.modal.motion = Some(Motion::Linear);
                self.modal.plane = 17;
                self.modal.relative = false;
                self.modal.spindle = 5;
                self.modal.wcs = 0;
            }
            actions.push(s);
        }
        Ok(actions)
    }

    fn arc_center(
        &self,
        m: Motion,
        from: [f64; 3],
        to: [f64; 3],
        offsets: &[Option<f64>; 3],
        r: Option<f64>,
        scale: f64,
    ) -> Result<[f64; 2], u8> {
        if let Some(r) = r {
            // GRBL's radius-format arc
            let x = to[0] - from[0];
            let y = to[1] - from[1];
            if x == 0.0 && y == 0.0 {
                return Err(33);
            }
            let mut r = r * scale;
            let mut h = 4.0 * r * r - x * x - y * y;
            if h < 0.0 {
                return Err(33);
            }
            h = -h.sqrt() / x.hypot(y);
            if m == Motion::ArcCcw {
                h = -h;
            }
            if r < 0.0 {
                h = -h;
                r = -r;
            }
            let _ = r;
            return Ok([from[0] + 0.5 * (x - y * h), from[1] + 0.5 * (y + x * h)]);
        }
        if offsets[0].is_none() && offsets[1].is_none() {
            return Err(35);
        }
        let ij = [
            offsets[0].unwrap_or(0.0) * scale,
            offsets[1].unwrap_or(0.0) * scale,
        ];
        if !arc_target_ok([from[0], from[1]], [to[0], to[1]], ij) {
            return Err(33);
        }
        Ok([from[0] + ij[0], from[1] + ij[1]])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(i: &mut Interpreter, l: &str) -> Result<Vec<Action>, u8> {
        i.execute(&clean_line(l))
    }

    #[test]
    fn grbl_error_codes_for_bad_lines() {
        let mut i = Interpreter::new();
        assert_eq!(run(&mut i, "G1 X10"), Err(22), "no feed yet");
        assert_eq!(run(&mut i, "G1 X1e5 F100"), Err(20), "E is not a GRBL word");
        assert_eq!(run(&mut i, "G1 X F100"), Err(2));
        assert_eq!(run(&mut i, "1 X2"), Err(1));
        assert_eq!(run(&mut i, "M6 T2"), Err(20), "GRBL 1.1 has no M6");
        assert_eq!(run(&mut i, "G0 G1 X1"), Err(21));
        assert_eq!(run(&mut i, "G1 X1 X2 F10"), Err(25));
        assert_eq!(run(&mut i, "G2 X10 Y0 I3 J0 F100"), Err(33));
        assert_eq!(run(&mut i, "G4"), Err(28));
        assert_eq!(run(&mut i, "G1 X1 F-5"), Err(4));
    }

    #[test]
    fn arcs_moves_and_modal_state() {
        let mut i = Interpreter::new();
        assert!(run(&mut i, "G21 G90 G17 G94").unwrap().is_empty());
        let a = run(&mut i, "G1 X10 F600 (cut)").unwrap();
        assert!(
            matches!(a[0], Action::Move { motion: Motion::Linear, to: [10.0, 0.0, 0.0], feed, .. } if feed == 600.0)
        );
        let a = run(&mut i, "G3 X0 Y10 Z-1 I-10 J0").unwrap();
        let Action::Move { center, to, .. } = &a[0] else {
            panic!()
        };
        assert_eq!(*center, Some([0.0, 0.0]));
        assert_eq!(*to, [0.0, 10.0, -1.0]);
        // modal G3 continues without a G word
        assert!(run(&mut i, "X-10 Y0 I0 J-10").is_ok());
        let a = run(&mut i, "G2 X10 Y0 R10").unwrap();
        let Action::Move {
            center: Some(c), ..
        } = a[0]
        else {
            panic!()
        };
        assert!(c[0].abs() < 1e-9 && c[1].abs() < 1e-9, "{c:?}");
        assert!(run(&mut i, "G4 P0.5").unwrap() == vec![Action::Dwell(0.5)]);
        assert!(arc_target_ok([0.0, 0.0], [2.0, 0.004], [1.0, 0.0]));
        // work offsets: G10 L2 sets G55's zero, G55 moves relative to it, G53 ignores it
        let mut i = Interpreter::new();
        assert!(run(&mut i, "G10 L2 P2 X10 Y20").unwrap().is_empty());
        let a = run(&mut i, "G55 G0 X1 Y1").unwrap();
        assert!(matches!(
            a[0],
            Action::Move {
                to: [11.0, 21.0, 0.0],
                ..
            }
        ));
        let a = run(&mut i, "G53 G0 X0").unwrap();
        assert!(matches!(
            a[0],
            Action::Move {
                to: [0.0, 21.0, 0.0],
                ..
            }
        ));
        assert_eq!(i.wco(), [10.0, 20.0, 0.0]);
        assert_eq!(run(&mut i, "G10 L2 X1"), Err(36));
        assert!(!arc_target_ok([0.0, 0.0], [2.0, 0.2], [1.0, 0.0]));
    }

    #[test]
    fn g28_goes_via_its_axis_words_to_the_stored_position_and_m6_holds_where_taken() {
        let ends = |acts: Vec<Action>| -> Vec<[f64; 3]> {
            acts.into_iter()
                .filter_map(|a| match a {
                    Action::Move { motion, to, .. } => {
                        assert_eq!(motion, Motion::Rapid);
                        Some(to)
                    }
                    _ => None,
                })
                .collect()
        };
        let mut i = Interpreter::new();
        run(&mut i, "G0 X10 Y20 Z5").unwrap();
        // Fusion's retract: G91 Z0 is the point where the tool is, then Z alone home
        assert_eq!(
            ends(run(&mut i, "G28 G91 Z0").unwrap()),
            [[10.0, 20.0, 5.0], [10.0, 20.0, 0.0]]
        );
        run(&mut i, "G90").unwrap();
        // a stored position, and G28 without axis words: every axis goes to it
        run(&mut i, "G0 X30 Y40 Z-2").unwrap();
        run(&mut i, "G28.1").unwrap();
        run(&mut i, "G0 X1 Y1 Z1").unwrap();
        assert_eq!(ends(run(&mut i, "G28").unwrap()), [[30.0, 40.0, -2.0]]);
        // with X: via X 5 (absolute, work frame), then X alone to the stored X
        run(&mut i, "G0 X0 Y0 Z0").unwrap();
        assert_eq!(
            ends(run(&mut i, "G28 X5").unwrap()),
            [[5.0, 0.0, 0.0], [30.0, 0.0, 0.0]]
        );
        // G30 has its own
        assert_eq!(ends(run(&mut i, "G30").unwrap()), [[0.0, 0.0, 0.0]]);
        // M6: error 20 on GRBL 1.1; a hold before the line's move where it is taken
        assert_eq!(run(&mut i, "T1 M6"), Err(20));
        i.m6_holds = true;
        let acts = run(&mut i, "T2 M6 G0 X3").unwrap();
        assert_eq!(acts[0], Action::Pause);
        assert!(matches!(acts[1], Action::Move { .. }));
        assert_eq!(i.modal.tool, 2);
    }
}
