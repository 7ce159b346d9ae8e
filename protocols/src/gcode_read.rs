//! A small G-code reader for previews and checks: G0/G1/G2/G3 (XY plane, I/J centres or R,
//! a negative R the long way round), G81/G82/G83 drilling cycles, G20/G21, G90/G91, G53 and
//! G28/G30, into the Toolpath IR. It takes programs as other CAM programs write them: `( … )`
//! and `;` comments (also mid-line), `N` numbers, `*NN` checksums, `%` tape marks, a `/`
//! block delete (the line runs: the switch is off, as GRBL, which ignores the `/`), lower-case
//! words and words without spaces (`g1x10y5`). What it cannot follow is refused naming the
//! line: arcs outside the XY plane (G18/G19), cutter radius compensation (G41/G42), other
//! canned cycles (G73, G76, G84–G89) and a drilling cycle in incremental mode.

use offset_core::geom::Point;
use offset_core::toolpath::{Move, Toolpath, P3};

/// Why a program could not be read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("line {line}: {message}")]
pub struct ReadError {
    pub line: usize,
    pub message: String,
}

/// Reads G-code text into moves. Words other than motion, units and distance modes are
/// ignored (spindle, coolant, tool changes, comments); the machine starts at the origin.
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
        if let Some(m) = reader
            .line(raw)
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
        }
    }
}

impl Reader {
    /// Reads one line; the work-frame move it makes, if any. The error is one sentence
    /// without the line number.
    pub fn line(&mut self, raw: &str) -> Result<Option<Move>, String> {
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
            let v: f64 = num
                .parse()
                .map_err(|_| format!("word {letter} has no number (\"{num}\")"))?;
            words.push((letter, v));
        }
        let scale = &mut self.scale;
        let mut target: [Option<f64>; 3] = [None; 3];
        let (mut ci, mut cj, mut cr) = (None, None, None);
        let mut outside_work_frame = false;
        // G10 sets an offset (its axis words move nothing); G38.2 probes, a feed move for
        // this line only
        let mut sets_offset = false;
        let mut probe = false;
        let (mut q, mut p) = (None, None);
        for &(l, v) in &words {
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
}
