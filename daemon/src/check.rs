//! Checks every program meets before it is stored: each move inside the machine's work area
//! (arcs by their extent, not their end points), no feed above its limit, and for G-code
//! files no settings or system lines and no M-code the machine does not allow.

use crate::config::MachineConfig;
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
    let mut first = true;
    let mut result = Ok(());
    let mut index = 0usize;
    let mut i_of = Vec::with_capacity(tp.moves.len());
    // `walk` skips moves that go nowhere; keep each walked move's index in `tp.moves`
    for (i, m) in tp.moves.iter().enumerate() {
        if matches!(
            m,
            Move::Rapid { .. }
                | Move::Linear { .. }
                | Move::Arc { .. }
                | Move::Stitch { .. }
                | Move::Jump { .. }
        ) {
            i_of.push(i);
        }
    }
    tp.walk(P3::default(), |from, m, to| {
        let i = i_of.get(index).copied().unwrap_or(index);
        index += 1;
        if result.is_err() {
            return;
        }
        if let (Some(max), Move::Linear { feed, .. } | Move::Arc { feed, .. }) =
            (machine.max_feed, m)
        {
            if *feed > max + 1e-9 {
                result = Err(format!(
                    "{}: the feed {} mm/min is above machine `{}`'s limit of {max} mm/min",
                    at(i),
                    feed,
                    machine.name
                ));
                return;
            }
        }
        if let Some(w) = &machine.work_area {
            let mut pts = vec![to];
            if !first {
                pts.push(from);
            }
            if let Move::Arc { center, ccw, .. } = m {
                let b = arc_segment(from.xy(), to.xy(), *center, *ccw).bounds();
                pts.push(P3::new(b.min.x, b.min.y, to.z.min(from.z)));
                pts.push(P3::new(b.max.x, b.max.y, to.z.max(from.z)));
            }
            for p in pts {
                let v = [p.x, p.y, p.z];
                for (k, axis) in ["X", "Y", "Z"].iter().enumerate() {
                    if v[k] < w.min[k] - 1e-9 || v[k] > w.max[k] + 1e-9 || !v[k].is_finite() {
                        let what = if matches!(m, Move::Arc { .. }) {
                            "the arc reaches"
                        } else {
                            "it goes to"
                        };
                        result = Err(format!(
                            "{}: {what} {axis} {:.3}, outside machine `{}`'s work area ({axis} {} to {})",
                            at(i),
                            v[k],
                            machine.name,
                            w.min[k],
                            w.max[k]
                        ));
                        return;
                    }
                }
            }
        }
        first = false;
    });
    result
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
    let mut lines = Vec::new();
    let mut source_lines = Vec::new();
    let mut percent_at = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let n = i + 1;
        let line = strip_comments(raw);
        if line.is_empty() {
            continue;
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
            percent_at.push((n, lines.len()));
            continue;
        }
        if line.starts_with('$') {
            return Err(format!(
                "{file}, line {n} `{line}`: settings and system commands ($…) are not part of a job; give them at the machine"
            ));
        }
        lines.push(line);
        source_lines.push(n);
    }
    // a `%` may only mark the start and the end of the program (tape marks)
    for &(n, before) in &percent_at {
        if before != 0 && before != lines.len() {
            return Err(format!(
                "{file}, line {n}: a `%` in the middle of the program (only the first and last lines may be `%`)"
            ));
        }
    }
    let mut mm_per_unit = 1.0;
    for (line, &n) in lines.iter().zip(&source_lines) {
        let words = words(line);
        for (letter, value) in &words {
            match (letter, value.parse::<f64>().ok()) {
                ('G', Some(20.0)) => mm_per_unit = 25.4,
                ('G', Some(21.0)) => mm_per_unit = 1.0,
                _ => {}
            }
        }
        for (letter, value) in words {
            let code = || value.parse::<f64>().ok();
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
                        let f = f * mm_per_unit;
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
    }
    let (read, move_lines) = gcode_read::read_with_lines(&lines.join("\n"))
        .map_err(|e| format!("{file}, line {}: {}", source_lines[e.line - 1], e.message))?;
    let at = |i: usize| {
        let k = move_lines[i] - 1;
        format!("{file}, line {} `{}`", source_lines[k], lines[k])
    };
    moves(&read, machine, &at)?;
    Ok(GcodeProgram {
        lines,
        source_lines,
        moves: read,
    })
}

/// A line without its `( … )` and `;` comments, trimmed.
pub fn strip_comments(raw: &str) -> String {
    let mut line = String::new();
    let mut in_paren = false;
    for c in raw.chars() {
        match c {
            _ if in_paren => in_paren = c != ')',
            '(' => in_paren = true,
            ';' => break,
            c => line.push(c),
        }
    }
    line.trim().to_string()
}

/// The words of a line: letter (upper case) and the number as written.
fn words(line: &str) -> Vec<(char, String)> {
    let mut out = Vec::new();
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        if c.is_ascii_alphabetic() {
            let mut v = String::new();
            while let Some(&d) = chars.peek() {
                if d.is_ascii_digit() || matches!(d, '.' | '-' | '+') {
                    v.push(d);
                    chars.next();
                } else if d == ' ' && v.is_empty() {
                    chars.next();
                } else {
                    break;
                }
            }
            out.push((c.to_ascii_uppercase(), v));
        }
    }
    out
}
