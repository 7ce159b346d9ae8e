//! A small G-code reader for previews: G0/G1/G2/G3 (XY plane, I/J centres or R), G20/G21, G90/G91, into the Toolpath IR.

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

/// The reader's modal state, one line at a time: for a program read as it streams in,
/// without holding its moves.
#[derive(Clone, Debug)]
pub struct Reader {
    pos: P3,
    motion: u8,
    scale: f64,
    absolute: bool,
    feed: f64,
}

impl Default for Reader {
    fn default() -> Self {
        Reader {
            pos: P3::default(),
            motion: 0,
            scale: 1.0,
            absolute: true,
            feed: 0.0,
        }
    }
}

impl Reader {
    /// Reads one line; the work-frame move it makes, if any. The error is one sentence
    /// without the line number.
    pub fn line(&mut self, raw: &str) -> Result<Option<Move>, String> {
        // strip ( … ) and ; comments
        let mut clean = String::new();
        let mut depth = 0;
        for ch in raw.chars() {
            match ch {
                '(' => depth += 1,
                ')' if depth > 0 => depth -= 1,
                ';' if depth == 0 => break,
                _ if depth == 0 => clean.push(ch.to_ascii_uppercase()),
                _ => {}
            }
        }
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
        for &(l, v) in &words {
            match l {
                'G' if v == 53.0 || v == 28.0 || v == 30.0 => outside_work_frame = true,
                'G' if v == 10.0 => sets_offset = true,
                'G' if (v - 38.2).abs() < 1e-9 => probe = true,
                'G' => match v {
                    v if v == 0.0 || v == 1.0 || v == 2.0 || v == 3.0 => self.motion = v as u8,
                    20.0 => *scale = 25.4,
                    21.0 => *scale = 1.0,
                    90.0 => self.absolute = true,
                    91.0 => self.absolute = false,
                    _ => {}
                },
                'X' => target[0] = Some(v),
                'Y' => target[1] = Some(v),
                'Z' => target[2] = Some(v),
                'I' => ci = Some(v * *scale),
                'J' => cj = Some(v * *scale),
                'R' => cr = Some(v * *scale),
                'F' => self.feed = v * *scale,
                _ => {}
            }
        }
        if sets_offset || target.iter().all(|t| t.is_none()) {
            return Ok(None);
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
            _ => {
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
        };
        self.pos = to;
        Ok(Some(m))
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
}
