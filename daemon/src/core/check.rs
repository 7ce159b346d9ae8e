//! Checks every program meets before it is stored: each move inside the machine's work area
//! (arcs by their extent, not their end points), no feed above its limit, and for G-code
//! files no settings or system lines and no M-code the machine does not allow.

use crate::core::machine::MachineConfig;
use machlink_protocols::gcode_read;
use offset_core::toolpath::{arc_segment, Move, Toolpath, P3};

/// How a move is named in a refusal.
pub type Where<'a> = dyn Fn(usize) -> String + 'a;

/// A planned move, by its place in the path.
pub fn planned_move(i: usize) -> String {
    format!("move {} of the planned path", i + 1)
}

/// Checks every move of `tp` against `machine`'s work area and feed limit; the refusal names
/// the move with `at`.
pub fn moves(tp: &Toolpath, machine: &MachineConfig, at: &Where<'_>) -> Result<(), String> {
    let mut check = MoveCheck::new(machine);
    for (i, m) in tp.moves.iter().enumerate() {
        check.step(m, &|| at(i))?;
    }
    Ok(())
}

/// The checks of [`moves`], one move at a time (for a program read as it streams in): the
/// position is followed as `Toolpath::walk` follows it, from the origin.
pub struct MoveCheck<'m> {
    machine: &'m MachineConfig,
    pos: P3,
    first: bool,
}

impl<'m> MoveCheck<'m> {
    pub fn new(machine: &'m MachineConfig) -> MoveCheck<'m> {
        MoveCheck {
            machine,
            pos: P3::default(),
            first: true,
        }
    }

    /// Checks move `m`; `at` names it in a refusal. Moves that go nowhere pass.
    pub fn step(&mut self, m: &Move, at: &dyn Fn() -> String) -> Result<(), String> {
        let from = self.pos;
        let to = match m {
            Move::Rapid { to } | Move::Linear { to, .. } | Move::Arc { to, .. } => *to,
            Move::Stitch { to } | Move::Jump { to } => P3::at_z(*to, from.z),
            Move::Drill { at, clear, .. } => P3::at_z(*at, *clear),
            _ => return Ok(()),
        };
        let machine = self.machine;
        if let (Some(max), Move::Linear { feed, .. } | Move::Arc { feed, .. }) =
            (machine.max_feed, m)
        {
            if *feed > max + 1e-9 {
                return Err(format!(
                    "{}: the feed {} mm/min is above machine `{}`'s limit of {max} mm/min",
                    at(),
                    feed,
                    machine.name
                ));
            }
        }
        if let Some(w) = &machine.work_area {
            let mut pts = vec![to];
            if !self.first {
                pts.push(from);
            }
            if let Move::Arc { center, ccw, .. } = m {
                let b = arc_segment(from.xy(), to.xy(), *center, *ccw).bounds();
                pts.push(P3::new(b.min.x, b.min.y, to.z.min(from.z)));
                pts.push(P3::new(b.max.x, b.max.y, to.z.max(from.z)));
            }
            if let Move::Drill {
                at,
                retract,
                bottom,
                ..
            } = m
            {
                // a hole goes down to its bottom; from a tool below the R plane, up to it
                pts.push(P3::at_z(*at, *bottom));
                pts.push(P3::at_z(*at, *retract));
                pts.push(P3::at_z(from.xy(), from.z.max(*retract)));
            }
            for p in pts {
                let v = [p.x, p.y, p.z];
                for (k, axis) in ["X", "Y", "Z"].iter().enumerate() {
                    if v[k] < w.min[k] - 1e-9 || v[k] > w.max[k] + 1e-9 || !v[k].is_finite() {
                        let what = if matches!(m, Move::Arc { .. }) {
                            "the arc reaches"
                        } else if matches!(m, Move::Drill { .. }) {
                            "the hole reaches"
                        } else {
                            "it goes to"
                        };
                        return Err(format!(
                            "{}: {what} {axis} {:.3}, outside machine `{}`'s work area ({axis} {} to {})",
                            at(),
                            v[k],
                            machine.name,
                            w.min[k],
                            w.max[k]
                        ));
                    }
                }
            }
        }
        self.first = false;
        self.pos = to;
        Ok(())
    }
}

/// A G-code file read for a machine: the lines to send (comments and blank lines dropped),
/// the line each comes from, and the moves they make.
#[derive(Clone, Debug)]
pub struct GcodeProgram {
    pub lines: Vec<String>,
    /// The 1-based line in the file of each program line.
    pub source_lines: Vec<usize>,
    pub moves: Toolpath,
}

/// Reads and checks a G-code file for `machine`: every line ASCII with no real-time
/// characters, no settings or system lines (`$…`), a `%` only as the tape marks around the
/// program, only allowed M-codes, no feed above the limit, every move in the work area.
pub fn gcode_program(
    file: &str,
    text: &str,
    machine: &MachineConfig,
) -> Result<GcodeProgram, String> {
    let mut check = GcodeCheck::new(file, machine);
    let mut lines = Vec::new();
    let mut source_lines = Vec::new();
    let mut moves = Toolpath::new("program");
    for (i, raw) in text.lines().enumerate() {
        if let Some(c) = check.line(i + 1, raw)? {
            lines.push(c.line);
            source_lines.push(i + 1);
            for m in c.moves {
                moves.push(m);
            }
        }
    }
    Ok(GcodeProgram {
        lines,
        source_lines,
        moves,
    })
}

/// A program line that passed the checks: the line to send, and the moves it makes (a tool
/// change, a dwell, a motion, a program stop, in that order).
#[derive(Clone, Debug)]
pub struct CheckedLine {
    pub line: String,
    pub moves: Vec<Move>,
}

/// The checks of [`gcode_program`], one line at a time, so a file can be checked as it
/// streams in without being held whole: every refusal names the file, the line and (for a
/// move) its text.
pub struct GcodeCheck<'m> {
    file: String,
    machine: &'m MachineConfig,
    mm_per_unit: f64,
    /// Program lines so far.
    kept: usize,
    /// A `%` that came after program lines: only the end of the program may follow it.
    closing_percent: Option<usize>,
    reader: gcode_read::Reader,
    moves: MoveCheck<'m>,
}

impl<'m> GcodeCheck<'m> {
    pub fn new(file: &str, machine: &'m MachineConfig) -> GcodeCheck<'m> {
        GcodeCheck {
            file: file.to_string(),
            machine,
            mm_per_unit: 1.0,
            kept: 0,
            closing_percent: None,
            reader: if machine.kind.gcode_runs_as_moves() {
                gcode_read::Reader::as_moves()
            } else {
                gcode_read::Reader::default()
            },
            moves: MoveCheck::new(machine),
        }
    }

    /// Program lines that passed so far.
    pub fn kept(&self) -> usize {
        self.kept
    }

    /// Checks line `n` (1-based) of the file; the line to send, or None for a comment, a
    /// blank line or a tape mark.
    pub fn line(&mut self, n: usize, raw: &str) -> Result<Option<CheckedLine>, String> {
        let file = &self.file;
        let machine = self.machine;
        let line = strip_comments(raw);
        if line.is_empty() {
            return Ok(None);
        }
        if let Some(c) = line
            .chars()
            .find(|&c| !c.is_ascii() || c.is_ascii_control() || matches!(c, '?' | '!' | '~'))
        {
            return Err(format!(
                "{file}, line {n}: the character {c:?} cannot be sent to the machine"
            ));
        }
        if line == "%" {
            // a `%` may only mark the start and the end of the program (tape marks)
            if self.kept > 0 && self.closing_percent.is_none() {
                self.closing_percent = Some(n);
            }
            return Ok(None);
        }
        if line.starts_with('$') {
            return Err(format!(
                "{file}, line {n} `{line}`: settings and system commands ($…) are not part of a job; give them at the machine"
            ));
        }
        if let Some(p) = self.closing_percent {
            return Err(format!(
                "{file}, line {p}: a `%` in the middle of the program (only the first and last lines may be `%`)"
            ));
        }
        let words = gcode_read::words(&line);
        for (letter, value) in &words {
            match (letter, value.parse::<f64>().ok()) {
                ('G', Some(20.0)) => self.mm_per_unit = 25.4,
                ('G', Some(21.0)) => self.mm_per_unit = 1.0,
                _ => {}
            }
        }
        let dialect = machine.kind.gcode_dialect();
        for (letter, value) in words {
            let code = || value.parse::<f64>().ok();
            if let Some(why) = dialect.and_then(|d| d.refuses(letter, &value)) {
                return Err(format!(
                    "{file}, line {n} `{line}`: {why} (machine `{}`, link = \"{}\")",
                    machine.name, machine.link
                ));
            }
            match letter {
                'M' => {
                    let ok = code().is_some_and(|m| {
                        m.fract() == 0.0 && machine.allowed_m_codes.contains(&(m as u32))
                    });
                    if !ok {
                        return Err(format!(
                            "{file}, line {n} `{line}`: M{value} is not allowed on machine `{}` (it allows {})",
                            machine.name,
                            machine
                                .allowed_m_codes
                                .iter()
                                .map(|m| format!("M{m}"))
                                .collect::<Vec<_>>()
                                .join(", ")
                        ));
                    }
                }
                'G' if matches!(code(), Some(g) if g == 10.0 || g == 92.0) => {
                    return Err(format!(
                        "{file}, line {n} `{line}`: G{value} changes the work offsets, which the job's checks cannot follow; set offsets at the machine"
                    ));
                }
                'F' => {
                    // checked on the F word, not only on cutting moves: `G0 X9 F9000`
                    // leaves F9000 in force for the next G1
                    if let (Some(max), Some(f)) = (machine.max_feed, code()) {
                        let f = f * self.mm_per_unit;
                        if f > max + 1e-9 {
                            return Err(format!(
                                "{file}, line {n} `{line}`: the feed {f} mm/min is above machine `{}`'s limit of {max} mm/min",
                                machine.name
                            ));
                        }
                    }
                }
                _ => {}
            }
        }
        // where the file runs as its moves, what the reader or the kind cannot follow is
        // the machine's refusal: the sentence names it
        let as_moves = machine.kind.gcode_runs_as_moves();
        let on_machine = || format!(" (machine `{}`, link = \"{}\")", machine.name, machine.link);
        let moves = self.reader.line_moves(&line).map_err(|e| {
            if as_moves {
                format!("{file}, line {n} `{line}`: {e}{}", on_machine())
            } else {
                format!("{file}, line {n}: {e}")
            }
        })?;
        for m in &moves {
            if let Some(why) = as_moves
                .then(|| machine.kind.gcode_move_refused(m))
                .flatten()
            {
                return Err(format!("{file}, line {n} `{line}`: {why}{}", on_machine()));
            }
            self.moves
                .step(m, &|| format!("{file}, line {n} `{line}`"))?;
        }
        self.kept += 1;
        Ok(Some(CheckedLine { line, moves }))
    }
}

/// A line as it is sent: without its `( … )` and `;` comments, `*NN` checksum and `/` block
/// delete, trimmed (`gcode_read::clean`).
pub fn strip_comments(raw: &str) -> String {
    gcode_read::clean(raw)
}
