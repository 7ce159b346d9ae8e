//! Resuming a G-code program at a line: the modal state and tool position the lines before
//! it leave behind, and the lines that bring the machine back there safely (retract, restore
//! the modes, spindle and coolant, rapid over the start point, plunge) before the line runs.
//!
//! No I/O: lines in, lines and the operator's description out. The GRBL link sends what
//! [`plan`] makes, and the daemon shows the same plan to the operator first.

use super::words;
use crate::link::ResumePlan;
use crate::program::{Units, UnitsError};
use std::ops::Range;

/// How a resume brings the machine back.
#[derive(Clone, Debug, PartialEq)]
pub struct ResumeOptions {
    /// How long to wait after starting the spindle before the tool moves down, s.
    pub spindle_dwell_s: f64,
}

impl Default for ResumeOptions {
    fn default() -> Self {
        ResumeOptions {
            spindle_dwell_s: 2.0,
        }
    }
}

/// What the lines up to some point leave behind, as GRBL keeps it.
#[derive(Clone, Debug, PartialEq)]
pub struct Modal {
    pub inches: bool,
    pub relative: bool,
    /// 17, 18 or 19.
    pub plane: u8,
    /// 54 to 59.
    pub wcs: u8,
    /// 0, 1, 2, 3, or None after G80.
    pub motion: Option<u8>,
    /// The F word in force, as written (in the units of the line that wrote it), and in mm/min.
    pub feed: Option<(String, f64)>,
    /// 3, 4 or 5.
    pub spindle: u8,
    /// The S word in force, as written.
    pub speed: Option<String>,
    pub mist: bool,
    pub flood: bool,
    /// Where the tool is, in the work frame, mm; None on an axis no absolute move has set
    /// (or after a move in machine coordinates).
    pub pos: [Option<f64>; 3],
    /// The feed of the last plunge (a feed move down in Z only), mm/min.
    pub plunge_feed: Option<f64>,
}

impl Default for Modal {
    fn default() -> Self {
        Modal {
            inches: false,
            relative: false,
            plane: 17,
            wcs: 54,
            motion: Some(0),
            feed: None,
            spindle: 5,
            speed: None,
            mist: false,
            flood: false,
            pos: [None; 3],
            plunge_feed: None,
        }
    }
}

impl Modal {
    fn scale(&self) -> f64 {
        if self.inches {
            25.4
        } else {
            1.0
        }
    }

    /// Applies one line, as GRBL would, within what a resume needs to know.
    pub fn apply(&mut self, line: &str) {
        let ws = words(line);
        let num = |v: &str| v.parse::<f64>().ok();
        // modes first (a line's G20 applies to its own coordinates)
        let mut motion_word = None;
        let mut machine_coords = false;
        let mut lost = false;
        for (letter, value) in &ws {
            match letter {
                'G' => match num(value).map(|g| (g * 10.0).round() as i64) {
                    Some(200) => self.inches = true,
                    Some(210) => self.inches = false,
                    Some(900) => self.relative = false,
                    Some(910) => self.relative = true,
                    Some(170) => self.plane = 17,
                    Some(180) => self.plane = 18,
                    Some(190) => self.plane = 19,
                    Some(g @ (540 | 550 | 560 | 570 | 580 | 590)) => {
                        self.wcs = (g / 10) as u8;
                        // a work offset changes what the work position of the tool is
                        self.pos = [None; 3];
                    }
                    Some(g @ (0 | 10 | 20 | 30)) => motion_word = Some((g / 10) as u8),
                    Some(800) => {
                        self.motion = None;
                    }
                    Some(530) => machine_coords = true,
                    // stored positions, offsets: the work position is no longer known
                    Some(280 | 300 | 100 | 920 | 921 | 922 | 923) => lost = true,
                    _ => {}
                },
                'M' => match num(value).map(|m| m.round() as i64) {
                    Some(3) => self.spindle = 3,
                    Some(4) => self.spindle = 4,
                    Some(5) => self.spindle = 5,
                    Some(7) => self.mist = true,
                    Some(8) => self.flood = true,
                    Some(9) => {
                        self.mist = false;
                        self.flood = false;
                    }
                    Some(2 | 30) => {
                        // GRBL's program end
                        self.motion = Some(1);
                        self.plane = 17;
                        self.relative = false;
                        self.wcs = 54;
                        self.spindle = 5;
                        self.mist = false;
                        self.flood = false;
                    }
                    _ => {}
                },
                'F' => {
                    if let Some(f) = num(value) {
                        self.feed = Some((value.clone(), f * self.scale()));
                    }
                }
                'S' => self.speed = Some(value.clone()),
                _ => {}
            }
        }
        if let Some(m) = motion_word {
            self.motion = Some(m);
        }
        if lost {
            self.pos = [None; 3];
            return;
        }
        let axes: Vec<(usize, f64)> = ws
            .iter()
            .filter_map(|(l, v)| {
                let k = match l {
                    'X' => 0,
                    'Y' => 1,
                    'Z' => 2,
                    _ => return None,
                };
                num(v).map(|v| (k, v * self.scale()))
            })
            .collect();
        if axes.is_empty() {
            return;
        }
        let from = self.pos;
        for (k, v) in axes.iter().copied() {
            self.pos[k] = if machine_coords {
                None
            } else if self.relative {
                self.pos[k].map(|p| p + v)
            } else {
                Some(v)
            };
        }
        // a feed move that only goes down in Z is a plunge
        let only_z = axes.iter().all(|(k, _)| *k == 2);
        if !machine_coords && only_z && matches!(self.motion, Some(1)) {
            if let (Some(z0), Some(z1)) = (from[2], self.pos[2]) {
                if z1 < z0 {
                    self.plunge_feed = self.feed.as_ref().map(|f| f.1);
                }
            }
        }
    }
}

/// Whether a line has an axis word, and whether it names its motion mode itself.
fn axis_and_motion(line: &str) -> (bool, bool) {
    let ws = words(line);
    let axis = ws.iter().any(|(l, _)| matches!(l, 'X' | 'Y' | 'Z'));
    let motion = ws.iter().any(|(l, v)| {
        *l == 'G'
            && v.parse::<f64>()
                .is_ok_and(|g| matches!((g * 10.0).round() as i64, 0 | 10 | 20 | 30 | 800))
    });
    (axis, motion)
}

/// The work position (mm) at the end of each line of `keep`, where it is known: element
/// `i - keep.start` for line `i` (the lines are read from the program's start, one at a
/// time, and only `keep`'s positions are held).
pub fn end_positions<'a>(
    lines: impl Into<Units<'a, String>>,
    keep: Range<usize>,
) -> Result<Vec<[Option<f64>; 3]>, UnitsError> {
    let mut m = Modal::default();
    let mut out = Vec::with_capacity(keep.len());
    for (i, l) in lines.into().iter(0..keep.end).enumerate() {
        m.apply(&l?);
        if i >= keep.start {
            out.push(m.pos);
        }
    }
    Ok(out)
}

/// The state the lines before `from` leave behind.
pub fn state_before<'a>(
    lines: impl Into<Units<'a, String>>,
    from: usize,
) -> Result<Modal, UnitsError> {
    let mut m = Modal::default();
    for l in lines.into().iter(0..from) {
        m.apply(&l?);
    }
    Ok(m)
}

/// The highest Z (work frame, mm) the program reaches: the height a resume retracts to.
pub fn safe_z<'a>(lines: impl Into<Units<'a, String>>) -> Result<Option<f64>, UnitsError> {
    let lines = lines.into();
    let mut m = Modal::default();
    let mut top: Option<f64> = None;
    for l in lines.iter(0..lines.len()) {
        m.apply(&l?);
        if let Some(z) = m.pos[2] {
            top = Some(top.map_or(z, |t: f64| t.max(z)));
        }
    }
    Ok(top)
}

/// A resume's lines and what they are for.
#[derive(Clone, Debug, PartialEq)]
pub struct Reposition {
    /// The lines to send before the program's line `from + 1`, each with the operator's
    /// words for it.
    pub lines: Vec<(String, String)>,
    /// A program line that must be sent changed: the modal arc motion (G2/G3) it relies on,
    /// written onto the first line at or after the resume point that moves without naming
    /// its motion (GRBL takes no G2/G3 without axis words, so the mode cannot be set alone).
    pub rewrite: Option<(usize, String)>,
}

/// The number as G-code writes it in the units in force.
fn coord(mm: f64, inches: bool) -> String {
    crate::gcode::num(if inches { mm / 25.4 } else { mm })
}

fn feed_word(mm_per_min: f64, inches: bool) -> String {
    let v = if inches {
        mm_per_min / 25.4
    } else {
        mm_per_min
    };
    let s = format!("{v:.3}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// The lines that bring the machine to where line `from + 1` starts, in the state the lines
/// before it left: units, distance mode, plane and work offset first, a retract to the
/// program's highest Z, the spindle (with `spindle_dwell_s` to spin up) and coolant, a rapid
/// over the start point, a plunge at the program's last plunge feed, then the motion mode
/// and feed. Nothing for a program that starts at its beginning. An error names the line
/// whose start cannot be known.
pub fn reposition<'a>(
    lines: impl Into<Units<'a, String>>,
    from: usize,
    opts: &ResumeOptions,
) -> Result<Reposition, String> {
    let lines = lines.into();
    if from == 0 || from >= lines.len() {
        return Ok(Reposition {
            lines: Vec::new(),
            rewrite: None,
        });
    }
    let s = state_before(lines, from).map_err(|e| e.to_string())?;
    let inch = s.inches;
    let n = from + 1;
    let mut out: Vec<(String, String)> = Vec::new();
    let units = if inch { "G20" } else { "G21" };
    out.push((
        format!("{units} G90 G{} G{} G94", s.plane, s.wcs),
        format!(
            "set {} units, absolute distances, plane G{} and work offset G{}, as line {n} expects them",
            if inch { "inch" } else { "millimetre" },
            s.plane,
            s.wcs
        ),
    ));
    let (Some(x), Some(y)) = (s.pos[0], s.pos[1]) else {
        return Err(format!(
            "cannot tell where line {n} starts: no absolute X and Y before it (in work offset G{}); resume from a later line",
            s.wcs
        ));
    };
    let top = safe_z(lines).map_err(|e| e.to_string())?;
    if let Some(t) = top {
        out.push((
            format!("G0 Z{}", coord(t, inch)),
            format!(
                "retract to Z{} (the program's highest Z)",
                crate::gcode::num(t)
            ),
        ));
    }
    match (s.spindle, &s.speed) {
        (3 | 4, speed) => {
            let m = if s.spindle == 3 { "M3" } else { "M4" };
            let line = match speed {
                Some(v) => format!("{m} S{v}"),
                None => m.to_string(),
            };
            out.push((
                line.clone(),
                format!(
                    "start the spindle {} ({line})",
                    if s.spindle == 3 {
                        "clockwise"
                    } else {
                        "counter-clockwise"
                    }
                ),
            ));
            if opts.spindle_dwell_s > 0.0 {
                let p = feed_word(opts.spindle_dwell_s, false);
                out.push((
                    format!("G4 P{p}"),
                    format!("wait {p} s for the spindle to reach speed"),
                ));
            }
        }
        _ => out.push(("M5".into(), "keep the spindle stopped (M5)".into())),
    }
    match (s.mist, s.flood) {
        (false, false) => {}
        (mist, flood) => {
            let mut w = Vec::new();
            if mist {
                w.push("M7");
            }
            if flood {
                w.push("M8");
            }
            let l = w.join(" ");
            out.push((l.clone(), format!("turn the coolant on ({l})")));
        }
    }
    out.push((
        format!("G0 X{} Y{}", coord(x, inch), coord(y, inch)),
        format!(
            "rapid to X{} Y{}, where line {n} starts",
            crate::gcode::num(x),
            crate::gcode::num(y)
        ),
    ));
    if let Some(z) = s.pos[2] {
        let below_top = top.is_some_and(|t| z < t - 1e-9);
        if below_top {
            let f = s
                .plunge_feed
                .or(s.feed.as_ref().map(|f| f.1))
                .unwrap_or(100.0);
            out.push((
                format!("G1 Z{} F{}", coord(z, inch), feed_word(f, inch)),
                format!(
                    "plunge to Z{} at F{} ({})",
                    crate::gcode::num(z),
                    feed_word(f, false),
                    if s.plunge_feed.is_some() {
                        "the program's last plunge feed"
                    } else {
                        "the feed in force, as the program has no plunge before this line"
                    }
                ),
            ));
        } else if top.is_none_or(|t| z > t + 1e-9) {
            out.push((
                format!("G0 Z{}", coord(z, inch)),
                format!("rapid to Z{}", crate::gcode::num(z)),
            ));
        }
    }
    // the modes line `from + 1` relies on
    let mut restore = Vec::new();
    if s.relative {
        restore.push("G91".to_string());
    }
    match s.motion {
        Some(m @ (0 | 1)) => restore.push(format!("G{m}")),
        None => restore.push("G80".into()),
        _ => {}
    }
    if let Some((f, _)) = &s.feed {
        restore.push(format!("F{f}"));
    }
    if !restore.is_empty() {
        let l = restore.join(" ");
        out.push((l.clone(), format!("restore {l}, as the program left them")));
    }
    let mut rewrite = None;
    if let Some(m @ (2 | 3)) = s.motion {
        // the first line that moves: if it does not name its motion, it runs in G2/G3
        for (k, l) in lines.iter(from..lines.len()).enumerate() {
            let (k, l) = (from + k, l.map_err(|e| e.to_string())?);
            let (axis, motion) = axis_and_motion(&l);
            if motion {
                break;
            }
            if axis {
                rewrite = Some((k, format!("G{m} {l}")));
                break;
            }
        }
    }
    Ok(Reposition {
        lines: out,
        rewrite,
    })
}

/// The plan the operator sees for a resume at `from` (0-based), in the order the link
/// carries it out.
pub fn plan<'a>(
    lines: impl Into<Units<'a, String>>,
    from: usize,
    opts: &ResumeOptions,
) -> Result<ResumePlan, String> {
    let lines = lines.into();
    if from >= lines.len() {
        return Ok(ResumePlan {
            from,
            steps: vec!["nothing is left to run".into()],
            moves: false,
        });
    }
    let r = reposition(lines, from, opts)?;
    let mut steps: Vec<String> = r
        .lines
        .iter()
        .map(|(l, why)| format!("{why}: `{l}`"))
        .collect();
    let first = match &r.rewrite {
        Some((k, l)) if *k == from => l.clone(),
        _ => lines.get(from).map_err(|e| e.to_string())?,
    };
    steps.push(format!("run the program from line {}: `{first}`", from + 1));
    if let Some((k, l)) = &r.rewrite {
        if *k != from {
            steps.push(format!(
                "send line {} as `{l}` (the arc mode it relies on)",
                k + 1
            ));
        }
    }
    Ok(ResumePlan {
        from,
        moves: !r.lines.is_empty(),
        steps,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ls(s: &[&str]) -> Vec<String> {
        s.iter().map(|l| l.to_string()).collect()
    }

    #[test]
    fn a_resume_retracts_restores_spins_up_rapids_and_plunges_before_the_line() {
        let p = ls(&[
            "G21 G90 G17 G94",
            "G55",
            "G0 Z5",
            "M3 S12000",
            "G0 X10 Y10",
            "G1 Z-1 F300",
            "G1 X20 F1200",
            "M8",
            "G2 X30 Y20 I10 J0",
            "X40 Y10 I0 J-10",
            "G0 Z5",
            "M2",
        ]);
        // resume at line 10, an arc continuing in modal G2, starting where line 9 ended
        let r = reposition(&p, 9, &ResumeOptions::default()).unwrap();
        let lines: Vec<&str> = r.lines.iter().map(|(l, _)| l.as_str()).collect();
        assert_eq!(
            lines,
            [
                "G21 G90 G17 G55 G94",
                "G0 Z5.000",
                "M3 S12000",
                "G4 P2",
                "M8",
                "G0 X30.000 Y20.000",
                "G1 Z-1.000 F300",
                "F1200",
            ]
        );
        assert_eq!(r.rewrite, Some((9, "G2 X40 Y10 I0 J-10".to_string())));
        let plan = plan(&p, 9, &ResumeOptions::default()).unwrap();
        assert!(plan.moves);
        assert!(
            plan.steps[0].contains("work offset G55"),
            "{:?}",
            plan.steps
        );
        assert!(plan.steps.last().unwrap().contains("line 10"));
    }

    #[test]
    fn a_resume_of_a_relative_inch_program_restores_g91_after_moving_in_g90() {
        let p = ls(&[
            "G20 G90",
            "G0 X1 Y1 Z0.2",
            "G1 Z-0.1 F10",
            "G91",
            "G1 X0.5",
            "Y0.5",
        ]);
        let r = reposition(&p, 5, &ResumeOptions::default()).unwrap();
        let lines: Vec<&str> = r.lines.iter().map(|(l, _)| l.as_str()).collect();
        assert_eq!(
            lines,
            [
                "G20 G90 G17 G54 G94",
                "G0 Z0.200",
                "M5",
                "G0 X1.500 Y1.000",
                "G1 Z-0.100 F10",
                "G91 G1 F10"
            ]
        );
        assert_eq!(r.rewrite, None);
    }

    #[test]
    fn a_line_whose_start_is_unknown_is_refused_naming_it() {
        let p = ls(&["G21", "G1 Z-1 F100", "G1 X5 Y5"]);
        let e = reposition(&p, 2, &ResumeOptions::default()).unwrap_err();
        assert!(e.contains("line 3"), "{e}");
        assert!(reposition(&p, 0, &ResumeOptions::default())
            .unwrap()
            .lines
            .is_empty());
    }
}
