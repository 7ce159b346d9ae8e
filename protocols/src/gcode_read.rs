//! A small G-code reader for previews and checks: G0/G1/G2/G3 (XY plane, I/J centres or R,
//! a negative R the long way round), G81/G82/G83 drilling cycles, G20/G21, G90/G91, G53 and
//! G28/G30, G4 dwells, tool changes (`M6` with the `T` of its line or an earlier one) and
//! program stops (`M0`, `M1`), into the Toolpath IR. It takes programs as other CAM programs
//! write them: `( … )` and `;` comments (also mid-line), `N` numbers, `*NN` checksums, `%`
//! tape marks, a `/` block delete (the line runs: the switch is off, as GRBL, which ignores
//! the `/`), lower-case words and words without spaces (`g1x10y5`). What it cannot follow is
//! refused naming the line: arcs outside the XY plane (G18/G19), cutter radius compensation
//! (G41/G42), other canned cycles (G73, G76, G84–G89) and a drilling cycle in incremental
//! mode. Read for a machine that runs the file as the moves read ([`Reader::as_moves`]), it
//! also refuses every word that would change what the machine does and that the moves
//! cannot carry: moves outside the work frame (G53, G28, G30), other work offsets, tool
//! length offsets other than the loaded tool's, probes, other feed modes, other axes.

use offset_core::geom::Point;
use offset_core::toolpath::{Move, Toolpath, P3};

/// Why a program could not be read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("line {line}: {message}")]
pub struct ReadError {
    pub line: usize,
    pub message: String,
}

/// Reads G-code text into moves: motion, dwells, tool changes and program stops; spindle,
/// coolant and comments are left out. The machine starts at the origin.
pub fn read(text: &str) -> Result<Toolpath, ReadError> {
    read_with_lines(text).map(|(tp, _)| tp)
}

/// Like [`read`], with the 1-based line each move comes from. Moves in machine coordinates
/// (`G53`) and to stored positions (`G28`, `G30`) are not work-frame moves: they are left
/// out, and the position after them is taken as their target.
pub fn read_with_lines(text: &str) -> Result<(Toolpath, Vec<usize>), ReadError> {
    let mut tp = Toolpath::new("program");
    let mut lines = Vec::new();
    let mut reader = Reader::default();
    for (n, raw) in text.lines().enumerate() {
        let line = n + 1;
        for m in reader
            .line_moves(raw)
            .map_err(|message| ReadError { line, message })?
        {
            tp.push(m);
            lines.push(line);
        }
    }
    Ok((tp, lines))
}

/// A line as a controller reads it: without its `( … )` and `;` comments, its `*NN`
/// checksum and a leading `/` (block delete), trimmed; the words as written.
pub fn clean(raw: &str) -> String {
    let mut line = String::new();
    let mut in_paren = false;
    for c in raw.chars() {
        match c {
            _ if in_paren => in_paren = c != ')',
            '(' => in_paren = true,
            ';' | '*' => break,
            c => line.push(c),
        }
    }
    let line = line.trim();
    line.strip_prefix('/').unwrap_or(line).trim().to_string()
}

/// The words of a cleaned line: letter (upper case) and the number as written (spaces
/// inside a word, as in `G 1`, are dropped).
pub fn words(line: &str) -> Vec<(char, String)> {
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

/// The plane arcs are in: G17 (XY), G18 (XZ), G19 (YZ).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Plane {
    Xy,
    Xz,
    Yz,
}

/// A drilling cycle in force (G81, G82, G83 until G80 or another motion): its kind, the
/// height it returns to, and its sticky words (Z bottom, R plane, Q peck, P dwell).
#[derive(Clone, Copy, Debug)]
struct Cycle {
    code: u8,
    /// The Z before the cycle began (G98 returns to it when it is above the R plane).
    initial_z: f64,
    bottom: Option<f64>,
    r: Option<f64>,
    q: f64,
    p: f64,
}

/// The reader's modal state, one line at a time: for a program read as it streams in,
/// without holding its moves.
#[derive(Clone, Debug)]
pub struct Reader {
    pos: P3,
    motion: u8,
    scale: f64,
    absolute: bool,
    feed: f64,
    plane: Plane,
    cycle: Option<Cycle>,
    /// G99: a drilling cycle returns to its R plane (G98, the default: to the Z it began at).
    to_r_plane: bool,
    /// The tool the last `T` word selected (the next `M6` loads it).
    selected: Option<u32>,
    /// The tool the last `M6` loaded.
    loaded: Option<u32>,
    /// Read for a machine that runs the file as the moves read: see [`Reader::as_moves`].
    as_moves: bool,
}

impl Default for Reader {
    fn default() -> Self {
        Reader {
            pos: P3::default(),
            motion: 0,
            scale: 1.0,
            absolute: true,
            feed: 0.0,
            plane: Plane::Xy,
            cycle: None,
            to_r_plane: false,
            selected: None,
            loaded: None,
            as_moves: false,
        }
    }
}

/// The G-codes a machine that runs the file as its moves follows (G43 with the loaded
/// tool's H besides, and the arcs of G18/G19, refused where they are used).
const FOLLOWED_AS_MOVES: &[f64] = &[
    0.0, 1.0, 2.0, 3.0, 4.0, 17.0, 18.0, 19.0, 20.0, 21.0, 40.0, 49.0, 54.0, 61.0, 61.1, 64.0,
    80.0, 81.0, 82.0, 83.0, 90.0, 91.0, 91.1, 94.0, 98.0, 99.0,
];

/// The M-codes a machine that runs the file as its moves follows: program stops, ends,
/// spindle, tool change, coolant (spindle and coolant are the device's own, as for a
/// planned program).
const M_FOLLOWED_AS_MOVES: &[f64] = &[0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 30.0];

/// Why a machine that runs the file as its moves cannot follow G-code `g` (None: it can).
fn not_followed_as_moves(g: f64) -> Option<String> {
    if FOLLOWED_AS_MOVES.iter().any(|c| (c - g).abs() < 1e-9) || g == 43.0 {
        return None;
    }
    let what = match g {
        53.0 => " (a move in machine coordinates)",
        28.0 | 30.0 => " (a move to a stored position)",
        28.1 | 30.1 => " (storing a position)",
        g if (55.0..60.0).contains(&g) => " (another work offset)",
        g if g > 43.0 && g < 44.0 => " (a tool length offset given in the program)",
        g if (38.0..39.0).contains(&g) => " (a probe)",
        93.0 => " (inverse time feed)",
        95.0 => " (feed per revolution)",
        90.1 => " (arc centres in absolute coordinates)",
        10.0 | 92.0 | 92.1 | 92.2 | 92.3 => " (setting an offset)",
        _ => "",
    };
    Some(format!(
        "G{g}{what} is not followed where the file runs as its moves, in the one work frame (G54) with the loaded tool"
    ))
}

impl Reader {
    /// A reader for a machine that runs the file as the moves read (a Modbus ring, CANopen
    /// drives): besides what [`Reader::default`] refuses, it refuses every word that would
    /// change what such a machine does and that the moves cannot carry (G53, G28/G30, G55–G59,
    /// G43 with another tool's H or before any tool change, G43.1, probes, G93/G95, G90.1,
    /// axes other than X, Y, Z, M-codes other than stops, ends, spindle, tool change and
    /// coolant, `O` words), and an `M6` no `T` word has selected a tool for.
    pub fn as_moves() -> Reader {
        Reader {
            as_moves: true,
            ..Reader::default()
        }
    }

    /// Reads one line; the work-frame move it makes, if any (a rapid, line, arc or hole;
    /// not its tool change, dwell or stop). The error is one sentence without the line number.
    pub fn line(&mut self, raw: &str) -> Result<Option<Move>, String> {
        Ok(self.line_moves(raw)?.into_iter().find(|m| {
            matches!(
                m,
                Move::Rapid { .. } | Move::Linear { .. } | Move::Arc { .. } | Move::Drill { .. }
            )
        }))
    }

    /// Reads one line; every move it makes, in the order a controller carries them out: the
    /// tool change (`M6`), the dwell (`G4 P…`, seconds), the motion, the program stop (`M0`,
    /// `M1`). The error is one sentence without the line number.
    pub fn line_moves(&mut self, raw: &str) -> Result<Vec<Move>, String> {
        let words = self.words_of(raw)?;
        let mut out = Vec::new();
        let (mut change, mut stop, mut dwell) = (false, false, false);
        let mut length_offset = None;
        let (mut h, mut p) = (None, None);
        for &(l, v) in &words {
            match l {
                'T' => {
                    if !(v >= 0.0 && v.fract() == 0.0 && v <= u32::MAX as f64) {
                        return Err(format!("T{v} is not a tool number"));
                    }
                    self.selected = Some(v as u32);
                }
                'M' if v == 6.0 => change = true,
                'M' if v == 0.0 || v == 1.0 => stop = true,
                'M' if self.as_moves && !M_FOLLOWED_AS_MOVES.contains(&v) => {
                    return Err(format!(
                        "M{v} is not followed where the file runs as its moves (only M0, M1, M2, M30, spindle, M6 and coolant are)"
                    ))
                }
                'G' if v == 4.0 => dwell = true,
                'G' if v == 43.0 => length_offset = Some(v),
                'G' if self.as_moves => {
                    if let Some(why) = not_followed_as_moves(v) {
                        return Err(why);
                    }
                }
                'H' => h = Some(v),
                'P' => p = Some(v),
                'A' | 'B' | 'C' | 'U' | 'V' | 'W' if self.as_moves => {
                    return Err(format!(
                        "the word {l}{v} (an axis besides X, Y and Z) is not followed where the file runs as its moves"
                    ))
                }
                _ => {}
            }
        }
        if change {
            match self.selected {
                Some(tool) => {
                    self.loaded = Some(tool);
                    out.push(Move::ToolChange {
                        tool,
                        name: String::new(),
                        geometry: None,
                    });
                }
                None if self.as_moves => return Err(
                    "M6 with no T word on its line or before it: which tool to load is not said"
                        .into(),
                ),
                None => {}
            }
        }
        if let (Some(_), true) = (length_offset, self.as_moves) {
            // the operator sets the length of the tool loaded at the tool stop; an offset of
            // any other tool the moves cannot carry
            match (self.loaded, h) {
                (Some(_), None) => {}
                (Some(t), Some(h)) if h == t as f64 => {}
                (Some(t), Some(h)) => {
                    return Err(format!(
                        "G43 H{h} (the length offset of tool {h}) is not followed: tool {t} is the one loaded, whose length the operator sets at its tool change"
                    ))
                }
                (None, _) => {
                    return Err(format!(
                        "G43{} (a tool length offset from the tool table) is not followed before a tool change (M6) has loaded the tool whose length the operator sets",
                        h.map(|h| format!(" H{h}")).unwrap_or_default()
                    ))
                }
            }
        }
        if dwell {
            match p {
                Some(s) if s.is_finite() && s >= 0.0 => out.push(Move::Dwell { seconds: s }),
                _ if !self.as_moves => {}
                Some(s) => return Err(format!("the dwell G4 P{s} is not a number of seconds")),
                None => return Err("the dwell G4 needs its P (seconds)".into()),
            }
        } else if let Some(m) = self.motion(&words)? {
            out.push(m);
        }
        if stop {
            out.push(Move::Stop);
        }
        Ok(out)
    }

    /// The words of line `raw`: letter and value, `%` and a `$` line's rest left out.
    fn words_of(&self, raw: &str) -> Result<Vec<(char, f64)>, String> {
        let clean = clean(raw).to_ascii_uppercase();
        let chars: Vec<char> = clean.chars().filter(|c| !c.is_whitespace()).collect();
        let mut words: Vec<(char, f64)> = Vec::new();
        let mut i = 0;
        while i < chars.len() {
            let letter = chars[i];
            if letter == '%' {
                i += 1;
                continue;
            }
            if !letter.is_ascii_alphabetic() {
                return Err(format!("expected a word letter, found '{letter}'"));
            }
            i += 1;
            let start = i;
            while i < chars.len() && (chars[i].is_ascii_digit() || "+-.".contains(chars[i])) {
                i += 1;
            }
            let num: String = chars[start..i].iter().collect();
            if letter == '$' {
                break;
            }
            if letter == 'O' && self.as_moves {
                // `o100 sub`, `o100 if […]`: what follows is no word
                return Err(format!(
                    "the word O{num} (a subroutine or a program number) is not followed where the file runs as its moves"
                ));
            }
            let v: f64 = num
                .parse()
                .map_err(|_| format!("word {letter} has no number (\"{num}\")"))?;
            words.push((letter, v));
        }
        Ok(words)
    }

    /// The work-frame move a line of `words` makes, if any.
    fn motion(&mut self, words: &[(char, f64)]) -> Result<Option<Move>, String> {
        let scale = &mut self.scale;
        let mut target: [Option<f64>; 3] = [None; 3];
        let (mut ci, mut cj, mut cr) = (None, None, None);
        let mut outside_work_frame = false;
        // G10 sets an offset (its axis words move nothing); G38.2 probes, a feed move for
        // this line only
        let mut sets_offset = false;
        let mut probe = false;
        let (mut q, mut p) = (None, None);
        for &(l, v) in words {
            match l {
                'G' if v == 53.0 || v == 28.0 || v == 30.0 => outside_work_frame = true,
                'G' if v == 10.0 => sets_offset = true,
                'G' if (v - 38.2).abs() < 1e-9 => probe = true,
                'G' => match v {
                    v if v == 0.0 || v == 1.0 || v == 2.0 || v == 3.0 => {
                        self.motion = v as u8;
                        self.cycle = None;
                    }
                    17.0 => self.plane = Plane::Xy,
                    18.0 => self.plane = Plane::Xz,
                    19.0 => self.plane = Plane::Yz,
                    20.0 => *scale = 25.4,
                    21.0 => *scale = 1.0,
                    41.0 | 42.0 => {
                        return Err(format!(
                            "cutter radius compensation (G{v}) is not followed: the tool would not go where the lines say; post the program without it (G40)"
                        ))
                    }
                    80.0 => {
                        self.cycle = None;
                        self.motion = 0xff;
                    }
                    81.0 | 82.0 | 83.0 => {
                        let initial_z = match self.cycle {
                            Some(c) => c.initial_z,
                            None => self.pos.z,
                        };
                        let (bottom, r) = self.cycle.map_or((None, None), |c| (c.bottom, c.r));
                        self.cycle = Some(Cycle {
                            code: v as u8,
                            initial_z,
                            bottom,
                            r,
                            q: 0.0,
                            p: 0.0,
                        });
                    }
                    73.0 | 76.0 | 84.0 | 85.0 | 86.0 | 87.0 | 88.0 | 89.0 => {
                        return Err(format!(
                            "the canned cycle G{v} is not read (only the drilling cycles G81, G82 and G83 are)"
                        ))
                    }
                    90.0 => self.absolute = true,
                    91.0 => self.absolute = false,
                    98.0 => self.to_r_plane = false,
                    99.0 => self.to_r_plane = true,
                    _ => {}
                },
                'X' => target[0] = Some(v),
                'Y' => target[1] = Some(v),
                'Z' => target[2] = Some(v),
                'I' => ci = Some(v * *scale),
                'J' => cj = Some(v * *scale),
                'R' => cr = Some(v * *scale),
                'Q' => q = Some(v * *scale),
                'P' => p = Some(v),
                'F' => self.feed = v * *scale,
                _ => {}
            }
        }
        if sets_offset || target.iter().all(|t| t.is_none()) {
            if let (Some(c), false) = (&mut self.cycle, outside_work_frame) {
                // R, Q and P given without a hole are kept for the holes that follow
                c.r = cr.or(c.r);
                c.q = q.unwrap_or(c.q);
                c.p = p.unwrap_or(c.p);
            }
            return Ok(None);
        }
        if let (Some(c), false) = (self.cycle, outside_work_frame || sets_offset) {
            return self.drill(c, target, cr, q, p).map(Some);
        }
        let pos = self.pos;
        let cur = [pos.x, pos.y, pos.z];
        let mut to = [0.0; 3];
        for k in 0..3 {
            to[k] = match target[k] {
                Some(v) if self.absolute => v * self.scale,
                Some(v) => cur[k] + v * self.scale,
                None => cur[k],
            };
        }
        let to = P3::new(to[0], to[1], to[2]);
        if !(to.x.is_finite() && to.y.is_finite() && to.z.is_finite()) {
            return Err("a coordinate is not a finite number".into());
        }
        if outside_work_frame {
            self.pos = to;
            return Ok(None);
        }
        let feed = self.feed;
        let m = match self.motion {
            _ if probe => Move::Linear { to, feed },
            0 => Move::Rapid { to },
            1 => Move::Linear { to, feed },
            2 | 3 => {
                if self.plane != Plane::Xy {
                    let g = if self.plane == Plane::Xz { 18 } else { 19 };
                    return Err(format!(
                        "an arc in the {} plane (G{g}) is not followed: arcs are read in the XY plane (G17) only",
                        if g == 18 { "XZ" } else { "YZ" }
                    ));
                }
                let ccw = self.motion == 3;
                let center = match (ci, cj, cr) {
                    (_, _, Some(r)) => radius_center(pos.xy(), to.xy(), r, ccw)
                        .ok_or_else(|| format!("arc radius {r} is too small for its end points"))?,
                    (i, j, None) if i.is_some() || j.is_some() => {
                        Point::new(pos.x + i.unwrap_or(0.0), pos.y + j.unwrap_or(0.0))
                    }
                    _ => return Err("an arc needs I/J or R".into()),
                };
                Move::Arc {
                    to,
                    center,
                    ccw,
                    feed,
                }
            }
            _ => return Err("an axis word without a motion in force (G0, G1, G2, G3)".into()),
        };
        self.pos = to;
        Ok(Some(m))
    }

    /// One hole of drilling cycle `c` at the line's X/Y (absolute mode only).
    fn drill(
        &mut self,
        mut c: Cycle,
        target: [Option<f64>; 3],
        r: Option<f64>,
        q: Option<f64>,
        p: Option<f64>,
    ) -> Result<Move, String> {
        if !self.absolute {
            return Err(format!(
                "the drilling cycle G{} in incremental mode (G91) is not read; post it in absolute mode (G90)",
                c.code
            ));
        }
        let s = self.scale;
        c.bottom = target[2].map(|z| z * s).or(c.bottom);
        c.r = r.or(c.r);
        c.q = q.unwrap_or(c.q);
        c.p = p.unwrap_or(c.p);
        let (Some(bottom), Some(retract)) = (c.bottom, c.r) else {
            return Err(format!(
                "the drilling cycle G{} needs its Z (bottom) and R (retract plane)",
                c.code
            ));
        };
        if c.code == 83 && c.q <= 0.0 {
            return Err("the peck drilling cycle G83 needs a Q (peck) above 0".into());
        }
        self.cycle = Some(c);
        let at = Point::new(
            target[0].map_or(self.pos.x, |x| x * s),
            target[1].map_or(self.pos.y, |y| y * s),
        );
        if !(at.x.is_finite() && at.y.is_finite() && bottom.is_finite() && retract.is_finite()) {
            return Err("a coordinate is not a finite number".into());
        }
        let clear = if self.to_r_plane {
            retract
        } else {
            c.initial_z.max(retract)
        };
        self.pos = P3::at_z(at, clear);
        Ok(Move::Drill {
            at,
            clear,
            retract,
            bottom,
            peck: if c.code == 83 { c.q } else { 0.0 },
            dwell: if c.code == 82 { c.p } else { 0.0 },
            feed: self.feed,
        })
    }
}

/// The centre of the arc of radius `r` from `a` to `b` (negative r: the long way round).
fn radius_center(a: Point, b: Point, r: f64, ccw: bool) -> Option<Point> {
    let chord = b - a;
    let c = chord.len();
    if c == 0.0 || r.abs() * 2.0 < c * (1.0 - 1e-9) {
        return None;
    }
    let h = (r * r - c * c / 4.0).max(0.0).sqrt();
    let mid = a.lerp(b, 0.5);
    let left = chord.unit().perp();
    // a short ccw arc has its centre on the left of the chord
    let on_left = ccw == (r > 0.0);
    Some(if on_left {
        mid + left * h
    } else {
        mid - left * h
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_motion_units_and_arcs() {
        let tp = read("G21 G90\nG0 X10 Y0 Z5 (go)\nG1 Z-1 F300\nG3 X-10 Y0 I-10 J0\nG20\nG91 G1 X1 ; inch\nG2 X1 Y1 R1").unwrap();
        assert_eq!(tp.moves.len(), 5);
        match &tp.moves[2] {
            Move::Arc {
                center, ccw, to, ..
            } => {
                assert!(*ccw && center.dist(Point::default()) < 1e-12 && to.x == -10.0)
            }
            m => panic!("{m:?}"),
        }
        match &tp.moves[3] {
            Move::Linear { to, .. } => assert!((to.x - 15.4).abs() < 1e-12),
            m => panic!("{m:?}"),
        }
        let e = read("G1 X1\nG1 Xabc").unwrap_err();
        assert_eq!(e.line, 2);
        assert!(read("G2 X5 Y0").unwrap_err().message.contains("I/J or R"));
    }

    /// Where each move of `text` ends.
    fn ends(text: &str) -> Vec<(f64, f64, f64)> {
        read(text)
            .unwrap()
            .moves
            .iter()
            .map(|m| match m {
                Move::Rapid { to } | Move::Linear { to, .. } | Move::Arc { to, .. } => {
                    (to.x, to.y, to.z)
                }
                Move::Drill { at, clear, .. } => (at.x, at.y, *clear),
                m => panic!("{m:?}"),
            })
            .collect()
    }

    fn near(a: &[(f64, f64, f64)], b: &[(f64, f64, f64)]) -> bool {
        a.len() == b.len()
            && a.iter().zip(b).all(|(p, q)| {
                (p.0 - q.0).abs() < 1e-9 && (p.1 - q.1).abs() < 1e-9 && (p.2 - q.2).abs() < 1e-9
            })
    }

    #[test]
    fn inches_are_read_as_millimetres_and_back() {
        let e = ends("G20 G90\nG0 X1 Y2 Z0.25\nG1 X-0.5 F10\nG21\nG1 X3");
        assert!(
            near(
                &e,
                &[(25.4, 50.8, 6.35), (-12.7, 50.8, 6.35), (3.0, 50.8, 6.35)]
            ),
            "{e:?}"
        );
        match &read("G20\nG1 X1 F10").unwrap().moves[0] {
            Move::Linear { feed, .. } => assert!((feed - 254.0).abs() < 1e-9),
            m => panic!("{m:?}"),
        }
    }

    #[test]
    fn r_arcs_take_the_short_way_and_a_negative_r_the_long_way() {
        let arc = |text: &str| match read(text).unwrap().moves.last().unwrap() {
            Move::Arc { center, ccw, .. } => (center.x, center.y, *ccw),
            m => panic!("{m:?}"),
        };
        let r = 50f64.sqrt();
        // (0,0) to (10,0) clockwise: the short way has its centre below the chord
        let (x, y, ccw) = arc(&format!("G1 X0 Y0 F100\nG2 X10 Y0 R{r}"));
        assert!((x - 5.0).abs() < 1e-9 && (y + 5.0).abs() < 1e-9 && !ccw);
        // R negative: three quarters of a turn, centre above
        let (x, y, _) = arc(&format!("G1 X0 Y0 F100\nG2 X10 Y0 R-{r}"));
        assert!((x - 5.0).abs() < 1e-9 && (y - 5.0).abs() < 1e-9);
        // counter-clockwise the other way round
        let (x, y, ccw) = arc(&format!("G3 X10 Y0 R{r}"));
        assert!((x - 5.0).abs() < 1e-9 && (y - 5.0).abs() < 1e-9 && ccw);
        // a half circle by R in inches
        let (x, y, _) = arc("G20\nG3 X2 Y0 R1");
        assert!((x - 25.4).abs() < 1e-9 && y.abs() < 1e-9);
        let e = read("G0 X0\nG2 X10 Y0 R4").unwrap_err();
        assert_eq!(e.line, 2);
        assert!(e.message.contains("too small"), "{e}");
    }

    #[test]
    fn an_incremental_block_moves_from_where_the_tool_is_then_absolute_again() {
        let e = ends("G90 G0 X10 Y10 Z5\nG91\nG1 X5 F100\nY5 Z-6\nG2 X5 Y-5 R5\nG90\nG1 X0 Y0");
        assert!(
            near(
                &e,
                &[
                    (10.0, 10.0, 5.0),
                    (15.0, 10.0, 5.0),
                    (15.0, 15.0, -1.0),
                    (20.0, 10.0, -1.0),
                    (0.0, 0.0, -1.0)
                ]
            ),
            "{e:?}"
        );
        // G28 G91 Z0 (Fusion's retract) moves nothing in the work frame; G53 neither
        let e = ends("G0 X1 Y1 Z1\nG28 G91 Z0\nG90\nG53 G0 Z-2\nG0 X2");
        assert_eq!(e.len(), 2, "{e:?}");
    }

    #[test]
    fn numbers_checksums_tape_marks_block_delete_comments_and_case_are_taken() {
        let text = "%\nN10 G21 G90 (metric)\nN20 G0 X1 Y2*57\n/N30 G0 X3\n\
                    G0 (move) X7 ; then Y9\ng1x10y5f300\nG1 X 11 Y 6 (mid-line) Z-1\n%\n";
        let e = ends(text);
        assert!(
            near(
                &e,
                &[
                    (1.0, 2.0, 0.0),
                    (3.0, 2.0, 0.0),
                    (7.0, 2.0, 0.0),
                    (10.0, 5.0, 0.0),
                    (11.0, 6.0, -1.0)
                ]
            ),
            "{e:?}"
        );
        match &read(text).unwrap().moves[3] {
            Move::Linear { feed, .. } => assert_eq!(*feed, 300.0),
            m => panic!("{m:?}"),
        }
        assert_eq!(clean("/N30 G0 X3*12 (c)"), "N30 G0 X3");
        assert_eq!(clean("G1 X1 ; G1 X2"), "G1 X1");
    }

    #[test]
    fn drilling_cycles_are_read_as_holes() {
        let tp = read("G21 G90\nG0 Z10\nG0 X5 Y5\nG98 G81 X5 Y5 Z-3 R2 F120\nX15\nG99 G83 X25 Z-6 Q2\nG80\nG0 Z10").unwrap();
        let holes: Vec<_> = tp
            .moves
            .iter()
            .filter_map(|m| match m {
                Move::Drill {
                    at,
                    clear,
                    retract,
                    bottom,
                    peck,
                    ..
                } => Some((at.x, at.y, *clear, *retract, *bottom, *peck)),
                _ => None,
            })
            .collect();
        assert_eq!(
            holes,
            [
                (5.0, 5.0, 10.0, 2.0, -3.0, 0.0),
                (15.0, 5.0, 10.0, 2.0, -3.0, 0.0),
                (25.0, 5.0, 2.0, 2.0, -6.0, 2.0)
            ]
        );
        assert!(read("G91 G81 X5 Y5 Z-3 R2")
            .unwrap_err()
            .message
            .contains("incremental"));
        assert!(read("G81 X5 Y5 R2")
            .unwrap_err()
            .message
            .contains("Z (bottom)"));
    }

    #[test]
    fn what_the_reader_cannot_follow_is_refused_naming_the_line() {
        for (text, line, says) in [
            ("G0 X0\nG18\nG2 X10 Z0 I5 K0", 3, "XZ plane (G18)"),
            ("G19 G3 Y10 Z0 J5 K0", 1, "YZ plane (G19)"),
            (
                "G0 X0\nG41 D1 G1 X10 F100",
                2,
                "cutter radius compensation (G41)",
            ),
            ("G42 X1", 1, "(G42)"),
            ("G0 Z5\nG0 X1\nG84 X1 Y1 Z-5 R1", 3, "G84 is not read"),
            ("G81 X1 Y1 Z-1 R1\nG80\nX5", 3, "without a motion"),
        ] {
            let e = read(text).unwrap_err();
            assert_eq!(e.line, line, "{text}: {e}");
            assert!(e.message.contains(says), "{text}: {e}");
        }
        // back in the XY plane, arcs are read again
        assert!(read("G18\nG17\nG2 X10 Y0 I5 J0").is_ok());
    }

    #[test]
    fn tool_changes_dwells_and_program_stops_become_their_moves_in_a_controllers_order() {
        let kinds = |text: &str, r: Reader| -> Vec<String> {
            let mut r = r;
            text.lines()
                .flat_map(|l| r.line_moves(l).unwrap())
                .map(|m| match m {
                    Move::ToolChange { tool, .. } => format!("T{tool}"),
                    Move::Stop => "stop".into(),
                    Move::Dwell { seconds } => format!("dwell {seconds}"),
                    Move::Rapid { .. } => "rapid".into(),
                    Move::Linear { .. } => "line".into(),
                    m => panic!("{m:?}"),
                })
                .collect()
        };
        // T on the line of M6 (either order) or before it; the change before the line's
        // motion, the stop after it
        for r in [Reader::default(), Reader::as_moves()] {
            assert_eq!(
                kinds(
                    "T1 M6\nG0 X1\nM6 T2 G0 X2\nT3\nG4 P1.5\nM6\nG1 X3 F100 M0\nM1",
                    r
                ),
                [
                    "T1",
                    "rapid",
                    "T2",
                    "rapid",
                    "dwell 1.5",
                    "T3",
                    "line",
                    "stop",
                    "stop"
                ]
            );
        }
        // the work-frame move of a line is still its motion
        let mut r = Reader::default();
        assert!(matches!(
            r.line("T4 M6 G0 X5").unwrap(),
            Some(Move::Rapid { .. })
        ));
        // read as previews read it, an M6 with no tool and what a GRBL runs pass
        assert!(read("M6\nG53 G0 Z0\nG43.1 Z2\nG1 A5 F100").is_ok());
    }

    #[test]
    fn read_as_moves_what_the_moves_cannot_carry_is_refused() {
        let refused = |text: &str| -> ReadError {
            let mut r = Reader::as_moves();
            for (n, l) in text.lines().enumerate() {
                if let Err(message) = r.line_moves(l) {
                    return ReadError {
                        line: n + 1,
                        message,
                    };
                }
            }
            panic!("{text} was not refused")
        };
        for (text, line, says) in [
            ("G0 X1\nG53 G0 Z0", 2, "G53 (a move in machine coordinates)"),
            ("G28 G91 Z0", 1, "G28 (a move to a stored position)"),
            ("G30", 1, "G30 (a move to a stored position)"),
            ("G0 X1\nG56", 2, "G56 (another work offset)"),
            ("T1 M6\nG43.1 Z3", 2, "G43.1 (a tool length offset given"),
            ("T1 M6\nG43 H2", 2, "tool 1 is the one loaded"),
            ("G43 H1", 1, "before a tool change (M6)"),
            ("G38.2 Z-5 F10", 1, "G38.2 (a probe)"),
            ("G93 G1 X1 F2", 1, "G93 (inverse time feed)"),
            ("G90.1", 1, "G90.1 (arc centres in absolute"),
            ("G1 X1 B3 F100", 1, "the word B3 (an axis"),
            ("O100 SUB", 1, "the word O100"),
            ("M98 P100", 1, "M98 is not followed"),
            ("G0 X1\nM6", 2, "no T word"),
            ("G4", 1, "needs its P"),
            ("T1.5 M6", 1, "T1.5 is not a tool number"),
            ("G7", 1, "G7 is not followed"),
        ] {
            let e = refused(text);
            assert_eq!(e.line, line, "{text}: {e}");
            assert!(e.message.contains(says), "{text}: {e}");
        }
        // G43 with the loaded tool's H, or none, is the loaded tool's length
        let mut r = Reader::as_moves();
        for l in [
            "T7",
            "M6",
            "G43 H7",
            "G43",
            "G49",
            "G54 G17 G40 G80 G90 G94 G21",
        ] {
            r.line_moves(l).unwrap_or_else(|e| panic!("{l}: {e}"));
        }
    }
}
