//! G-code posts: GRBL, LinuxCNC and a generic dialect, from the Toolpath IR to program lines.
//!
//! Every program is absolute millimetres (`G21 G90 G17 G94`), with fixed three-decimal
//! numbers (never exponents, never `-0.000`), the feed written only when it changes, arcs as
//! `G2`/`G3` with `I`/`J` (helical when Z changes), and a rapid to a safe height before the
//! first move and after the last. For GRBL the lines also carry no comments (but the one
//! naming the tool at a tool change), no byte above 0x7f and at most 80 characters, and
//! each arc is re-centred after its end points are rounded so that GRBL's own arc check
//! (error:33) passes. GRBL has no tool changer (`M6` is error:20 there): a tool change
//! becomes a program stop (`M5`, `M0 (load T2: 6 mm flat end mill)`) at which the operator
//! swaps the tool and resumes with cycle start; other dialects write `T2 M6`. Drilling
//! cycles are canned cycles (G81/G82/G83, G98) for LinuxCNC and generic, and the same
//! rapids and feeds spelt out for GRBL, which has none.

use crate::post::{lines_file, Post, PostError};
use offset_core::toolpath::arc_segment;
use offset_core::{Move, Point, Segment, Toolpath, P3};
use serde::{Deserialize, Serialize};

/// Which controller the G-code is for.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Dialect {
    #[default]
    Grbl,
    Linuxcnc,
    Generic,
}

impl Dialect {
    /// Why a controller of this dialect cannot run word `letter``value` of a G-code file (as
    /// written, `value` the number's text), or None. GRBL 1.1 runs the G-codes of its
    /// documentation (docs/grbl.md) and the words F I J K L N P R S T X Y Z (A B C where
    /// compiled in); anything else is its error:20 or error:22 in the middle of a job, so it
    /// is refused before. M-codes are each machine's `allowed_m_codes`. Other dialects: None.
    pub fn refuses(&self, letter: char, value: &str) -> Option<String> {
        if *self != Dialect::Grbl {
            return None;
        }
        const GRBL_G: &[f64] = &[
            0.0, 1.0, 2.0, 3.0, 4.0, 10.0, 17.0, 18.0, 19.0, 20.0, 21.0, 28.0, 28.1, 30.0, 30.1,
            38.2, 38.3, 38.4, 38.5, 40.0, 43.1, 49.0, 53.0, 54.0, 55.0, 56.0, 57.0, 58.0, 59.0,
            61.0, 80.0, 90.0, 91.0, 91.1, 92.0, 92.1, 93.0, 94.0,
        ];
        match letter {
            'G' => {
                let g: f64 = value.parse().ok()?;
                if GRBL_G.iter().any(|c| (c - g).abs() < 1e-9) {
                    return None;
                }
                let what = match g {
                    g if (73.0..=89.0).contains(&g) => " (a canned cycle)",
                    98.0 | 99.0 => " (a canned cycle's return height)",
                    41.0 | 42.0 => " (cutter radius compensation)",
                    43.0 => " (a tool length offset from a tool table; GRBL has G43.1)",
                    64.0 => " (path blending)",
                    _ => "",
                };
                Some(format!("G{value}{what} is not a G-code GRBL 1.1 runs"))
            }
            'F' | 'I' | 'J' | 'K' | 'L' | 'N' | 'P' | 'R' | 'S' | 'T' | 'X' | 'Y' | 'Z' | 'A'
            | 'B' | 'C' | 'M' => None,
            other => {
                let what = match other {
                    'H' => " (a tool length offset number)",
                    'D' => " (a cutter compensation number)",
                    'Q' => " (a canned cycle's peck)",
                    'O' => " (a subroutine or a program number)",
                    _ => "",
                };
                Some(format!(
                    "the word {other}{value}{what} is not one GRBL 1.1 takes"
                ))
            }
        }
    }
}

/// Settings of one post run.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct GcodeOptions {
    pub dialect: Dialect,
    /// Height (mm) of the rapid before the first move and after the last; None takes the
    /// highest Z the tool path itself reaches (its own clearance).
    pub safe_z: Option<f64>,
    /// Lines written after the standard preamble (`G21 G90 G17 G94`).
    pub header: Vec<String>,
    /// Lines written before the program end.
    pub footer: Vec<String>,
    /// The machine's work envelope, mm: every position the path reaches (arc extremes
    /// included) must lie within it, or the post fails before writing anything.
    pub envelope_min: Option<[f64; 3]>,
    pub envelope_max: Option<[f64; 3]>,
    /// End with `M30` instead of `M2`.
    pub end_with_m30: bool,
}

/// Why a tool path could not be posted.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GcodeError {
    #[error(
        "move {index} reaches {axis}={value:.3}, beyond the machine's {axis} {side} of {limit:.3}"
    )]
    OutsideEnvelope {
        index: usize,
        axis: char,
        value: f64,
        limit: f64,
        side: &'static str,
    },
    #[error("the safe height Z={value:.3} is beyond the machine's Z {side} of {limit:.3}")]
    SafeZOutsideEnvelope {
        value: f64,
        limit: f64,
        side: &'static str,
    },
    #[error("move {index} holds a number that is not finite (NaN or infinite)")]
    NotFinite { index: usize },
    #[error("move {index} cuts at feed {feed} mm/min; a cutting feed must be above 0")]
    BadFeed { index: usize, feed: f64 },
    #[error("move {index} is an arc but the tool's position before it is unknown; start the path with a rapid or a line")]
    UnknownStart { index: usize },
    #[error("move {index} is a sewing move ({what}), which G-code cannot express")]
    SewingMove { index: usize, what: &'static str },
    #[error("move {index} drills from Z={clear:.3} through the R plane Z={retract:.3} to Z={bottom:.3}; they must go down in that order")]
    BadDrill {
        index: usize,
        clear: f64,
        retract: f64,
        bottom: f64,
    },
    #[error("G-code line {line} is {len} characters long; GRBL takes at most 80")]
    LineTooLong { line: usize, len: usize },
    #[error("the {place} line {text:?} cannot be sent: {why}")]
    BadExtraLine {
        place: &'static str,
        text: String,
        why: &'static str,
    },
}

/// GRBL's longest line, in characters.
pub const GRBL_MAX_LINE: usize = 80;
/// Decimals of every coordinate.
pub const DECIMALS: usize = 3;
/// Arcs whose radius is below this (mm) are written as straight lines.
pub const MIN_ARC_RADIUS: f64 = 0.01;
/// Arcs that depart from their chord by less than this (mm) are written as straight lines.
const MAX_SAGITTA_AS_LINE: f64 = 0.0002;
/// A written arc may stray this far (mm) from the planned one before it is flattened.
const MAX_ARC_DEVIATION: f64 = 0.005;

/// The planned arc, ready for distance questions without trigonometry: whether a point's
/// direction from the centre lies within the sweep is decided by cross products.
struct PlannedArc {
    c: Point,
    r: f64,
    /// start and end, as vectors from the centre
    va: Point,
    vb: Point,
    a: Point,
    b: Point,
    /// +1 counter-clockwise, -1 clockwise
    s: f64,
    /// the sweep exceeds a half turn (a full turn when the ends coincide, as
    /// `Segment::sweep` measures it)
    long: bool,
}

impl PlannedArc {
    fn new(seg: &Segment) -> Option<PlannedArc> {
        let Segment::Arc {
            a,
            b,
            center,
            radius,
            ccw,
        } = *seg
        else {
            return None;
        };
        let (va, vb) = (a - center, b - center);
        let s = if ccw { 1.0 } else { -1.0 };
        Some(PlannedArc {
            c: center,
            r: radius,
            va,
            vb,
            a,
            b,
            s,
            long: a == b || s * va.cross(vb) < 0.0,
        })
    }

    /// Distance from `p` to the arc (what `Segment::distance_to` answers).
    fn distance_to(&self, p: Point) -> f64 {
        let v = p - self.c;
        let len = v.len();
        if len > 0.0 {
            let after_start = self.s * self.va.cross(v) >= 0.0;
            let before_end = self.s * v.cross(self.vb) >= 0.0;
            let within = if self.long {
                self.a == self.b || after_start || before_end
            } else {
                after_start && before_end
            };
            if within {
                return (len - self.r).abs();
            }
        }
        p.dist(self.a).min(p.dist(self.b))
    }
}

/// The written arc's sweep about `c` from `a` to `b` as GRBL runs it (and
/// [`written_arc_deviation`] walks it): signed, nonzero, at most a full turn.
fn written_sweep(va: Point, vb: Point, ccw: bool) -> f64 {
    let tau = std::f64::consts::TAU;
    let mut s = va.cross(vb).atan2(va.dot(vb));
    if ccw {
        while s <= 1e-12 {
            s += tau;
        }
    } else {
        while s >= -1e-12 {
            s -= tau;
        }
    }
    s
}

/// The order in which [`written_arc_deviation`] asks the distance of its 25 points: the
/// end first (the written end moved onto the candidate's circle, off by the error GRBL's
/// check measures), then the middle and the quarters, where a centre that loses strays
/// most, then the rest. The order changes neither the maximum nor whether a walk reaches
/// its cutoff.
const WALK_ORDER: [usize; 25] = [
    24, 12, 6, 18, 3, 9, 15, 21, 0, 1, 2, 4, 5, 7, 8, 10, 11, 13, 14, 16, 17, 19, 20, 22, 23,
];

/// How far the arc GRBL runs from `a` about `c` to `b` strays from the planned arc: 25
/// points along it, stepped by one rotation (one `atan2` and one `sin_cos` per arc, not a
/// `sin_cos` and four `atan2` per point), their distances asked in [`WALK_ORDER`]. The walk
/// stops at the first point `cutoff` or more away (the candidate has lost then; the value
/// returned is at least `cutoff`); otherwise it returns the largest of the 25 distances.
fn written_arc_deviation(
    a: Point,
    b: Point,
    c: Point,
    ccw: bool,
    planned: &PlannedArc,
    cutoff: f64,
) -> f64 {
    let (va, vb) = (a - c, b - c);
    let r = va.len();
    let s = written_sweep(va, vb, ccw);
    let (sin, cos) = (s / 24.0).sin_cos();
    let mut u = if r > 0.0 {
        va * (1.0 / r)
    } else {
        Point::new(1.0, 0.0)
    };
    let mut points = [c; 25];
    for p in &mut points {
        *p = c + u * r;
        u = Point::new(u.x * cos - u.y * sin, u.x * sin + u.y * cos);
    }
    let mut worst: f64 = 0.0;
    for k in WALK_ORDER {
        worst = worst.max(planned.distance_to(points[k]));
        if worst >= cutoff {
            break;
        }
    }
    worst
}

/// A lower bound on what [`written_arc_deviation`] returns for the arc from `a` about `c`
/// to `b`: the distances of two of its points found without the walk, its end (b moved
/// onto the circle) and, when the sweep is clearly short or long and not near a half turn,
/// its middle (on the bisector of the ends' directions), less a margin for the walk's
/// rounding (the distance is 1-Lipschitz, so a point off by ε changes it by at most ε).
/// A candidate whose floor is already past the best so far is not walked: the walk would
/// stop at its cutoff there and the candidate lose.
fn written_arc_floor(a: Point, b: Point, c: Point, ccw: bool, planned: &PlannedArc) -> f64 {
    let (va, vb) = (a - c, b - c);
    let (r, lb) = (va.len(), vb.len());
    if !(r > 0.0 && lb > 0.0) {
        return 0.0;
    }
    let (ua, ub) = (va * (1.0 / r), vb * (1.0 / lb));
    let mut floor = planned.distance_to(c + ub * r);
    let turn = if ccw { 1.0 } else { -1.0 } * ua.cross(ub);
    let sum = ua + ub;
    let sum_len = sum.len();
    if turn.abs() > 1e-9 && sum_len >= 0.5 {
        // short (the turn's sine positive in the arc's direction): the middle is on the
        // sum's side; long: opposite it
        let mid = sum * (if turn > 0.0 { 1.0 } else { -1.0 } / sum_len);
        floor = floor.max(planned.distance_to(c + mid * r));
    }
    floor - 1e-12 * (1.0 + c.len() + r)
}

/// An upper bound, in closed form, on what [`written_arc_deviation`] returns for the arc
/// from `a` about `c` to `b` (without a cutoff), or None where the argument below does not
/// apply. A few square roots and cross products instead of 25 points.
///
/// Let C, R, A, B be the planned centre, radius, start and end, δ = c − C, d = |δ| and
/// r = |a − c|. When d ≤ r / 10, C lies inside the written circle, so the direction from C
/// turns one way along the written arc; seen from C the arc then runs from a's direction
/// (β₀ past A's, positive inside the plan's sweep S) to b*'s (β₁ past B's, positive
/// beyond it), b* being b moved onto the written circle, where the walk ends. With both β
/// under 0.1 rad and the written sweep within 1 rad of S − β₀ + β₁ (no turn more or less),
/// every walked point lies at an angle in [β₀, S + β₁] from A's. Those within [0, S] are
/// within the sweep: their distance is the radial one, | |p − C| − R |, and |p − C| =
/// |δ + r u| runs between its values at the written arc's ends and at u = ±δ/d when that
/// direction lies within the written sweep (there it is r ± d): so the largest radial
/// distance is the largest of those. Points before A are within max(|a − A|, the radial
/// bound) of A (the distance to A along a short piece of a circle is largest at an end of
/// the piece, and where the piece crosses the ray through A it is the radial distance);
/// points beyond B likewise of B, whose own radius may differ from R. A margin covers the
/// rounding of the walk's rotations.
fn written_arc_bound(
    a: Point,
    b: Point,
    c: Point,
    ccw: bool,
    planned: &PlannedArc,
    planned_sweep: f64,
) -> Option<f64> {
    let (va, vb) = (a - c, b - c);
    let r = va.len();
    let delta = c - planned.c;
    let d = delta.len();
    let lb = vb.len();
    // (a planned sweep that `distance_to` does not see as the same long or short arc —
    // a full turn between two ends in one direction — is left to the walk)
    let consistent = planned.long == (planned_sweep.abs() > std::f64::consts::PI);
    if !(r > 0.0 && lb > 0.0 && d <= 0.1 * r) || planned.a == planned.b || !consistent {
        return None;
    }
    let sw = written_sweep(va, vb, ccw).abs();
    let b_star = c + vb * (r / lb);
    let s = planned.s;
    // the written ends seen from the planned centre, against the planned ends
    let qa = a - planned.c;
    let (cross0, dot0) = (s * planned.va.cross(qa), planned.va.dot(qa));
    let qb = b_star - planned.c;
    let (cross1, dot1) = (s * planned.vb.cross(qb), planned.vb.dot(qb));
    if !(dot0 > 0.0 && cross0.abs() <= 0.1 * dot0 && dot1 > 0.0 && cross1.abs() <= 0.1 * dot1) {
        return None;
    }
    // (within 0.1 rad the tangent is the angle to within 0.4 %: ample against 1 rad)
    let (beta0, beta1) = (cross0 / dot0, cross1 / dot1);
    let turn_off = (sw - (planned_sweep.abs() - beta0 + beta1)).abs();
    if turn_off.is_nan() || turn_off >= 1.0 {
        return None;
    }
    let big_r = planned.r;
    let mut radial = (qa.len() - big_r).abs().max((qb.len() - big_r).abs());
    if d > 0.0 {
        let w = delta * (1.0 / d);
        // whether a direction lies within the written sweep (on its edge counts as in:
        // a bound may take a value the arc does not reach)
        let within = |w: Point| {
            let after_start = s * va.cross(w) >= -1e-9 * r;
            let before_end = s * w.cross(vb) >= -1e-9 * lb;
            if sw <= std::f64::consts::PI {
                after_start && before_end
            } else {
                after_start || before_end
            }
        };
        if within(w) {
            radial = radial.max((r + d - big_r).abs());
        }
        if within(-w) {
            radial = radial.max((r - d - big_r).abs());
        }
    }
    let b_radius = (planned.vb.len() - big_r).abs();
    let ends = a.dist(planned.a).max(b_star.dist(planned.b));
    let margin = 1e-12 * (1.0 + c.len() + planned.c.len() + r);
    Some((radial + b_radius).max(ends) + margin)
}

/// `v` in thousandths, rounded as `format!("{v:.3}")` rounds it: to nearest from the exact
/// value of the double, ties to even. The double product 1000 v decides it unless it lands
/// on a half exactly; then exact integer arithmetic on the double's significand and
/// exponent ([`thousandths_exact`]), so no near tie is left to the float formatter. None for
/// non-finite values and where the count reaches 2⁵³ (beyond 9·10¹² mm, where k / 1000
/// would round twice).
fn thousandths(v: f64) -> Option<i64> {
    // First the double product t = 1000 v, rounded once. Below 2⁵¹ every n + ½ is a
    // double, and rounding is monotonic: if t lies above n + ½ so does the exact product,
    // if below, below. Only t = n + ½ exactly leaves the side open, and that (rare) case
    // takes the exact arithmetic below. (Floor and fraction of such a t are exact.)
    let t = v * 1000.0;
    if t.abs() < (1u64 << 51) as f64 {
        // the floor through an integer (`f64::floor` is a library call on x86-64)
        let mut whole = t as i64;
        if whole as f64 > t {
            whole -= 1;
        }
        let fraction = t - whole as f64;
        if fraction != 0.5 {
            return Some(whole + i64::from(fraction > 0.5));
        }
    }
    thousandths_exact(v)
}

/// [`thousandths`] by exact integer arithmetic (v = m · 2^e, so 1000 v = 1000 m · 2^e, split
/// at the binary point), for the products that land on a half and the large values.
fn thousandths_exact(v: f64) -> Option<i64> {
    if !v.is_finite() {
        return None;
    }
    let bits = v.to_bits();
    let biased = ((bits >> 52) & 0x7ff) as i32;
    let fraction = bits & ((1u64 << 52) - 1);
    let (m, e) = if biased == 0 {
        (fraction, -1074)
    } else {
        (fraction | (1u64 << 52), biased - 1075)
    };
    if e >= 0 {
        // an integer of at least 2^52: 1000 times it is past 2^53
        return if m == 0 { Some(0) } else { None };
    }
    let n = 1000u128 * m as u128; // below 2^63
    let s = (-e) as u32;
    let k = if s >= 127 {
        0 // n < 2^63 < 2^(s-1): less than half a thousandth
    } else {
        let q = n >> s;
        let r = n - (q << s);
        let half = 1u128 << (s - 1);
        if r > half || (r == half && q & 1 == 1) {
            q + 1
        } else {
            q
        }
    };
    if k >= 1u128 << 53 {
        return None;
    }
    let k = k as i64;
    Some(if bits >> 63 == 1 { -k } else { k })
}

/// Appends `v` as written: three decimals, no exponent, no negative zero. A fixed-decimal
/// writer (an integer count of thousandths, digit by digit); the general float formatter
/// only beyond 9·10¹² mm (no planned coordinate: shapes beyond ±10⁷ mm are refused) and for
/// non-finite values (refused before anything is written).
pub fn push_num(out: &mut String, v: f64) {
    let Some(k) = thousandths(v) else {
        let s = format!("{v:.DECIMALS$}");
        if s.strip_prefix('-')
            .is_some_and(|r| r.bytes().all(|b| b == b'0' || b == b'.'))
        {
            out.push_str(&s[1..]);
        } else {
            out.push_str(&s);
        }
        return;
    };
    // written right to left into a buffer, then appended at once: `-`, the integer digits,
    // `.`, three decimals (k < 2⁵³: at most 16 digits)
    let m = k.unsigned_abs();
    let (mut int, frac) = (m / 1000, m % 1000);
    let mut text = [0u8; 24];
    let mut i = text.len() - 4;
    text[i] = b'.';
    text[i + 1] = b'0' + (frac / 100) as u8;
    text[i + 2] = b'0' + (frac / 10 % 10) as u8;
    text[i + 3] = b'0' + (frac % 10) as u8;
    loop {
        i -= 1;
        text[i] = b'0' + (int % 10) as u8;
        int /= 10;
        if int == 0 {
            break;
        }
    }
    if k < 0 {
        i -= 1;
        text[i] = b'-';
    }
    // byte by byte as chars: a check that the buffer is UTF-8 cost more than the pushes
    out.reserve(text.len() - i);
    for &d in &text[i..] {
        out.push(char::from(d));
    }
}

/// A coordinate as written: three decimals, no exponent, no negative zero.
pub fn num(v: f64) -> String {
    let mut s = String::with_capacity(12);
    push_num(&mut s, v);
    s
}

/// Whether two coordinates are written alike.
fn same_written(a: f64, b: f64) -> bool {
    match (thousandths(a), thousandths(b)) {
        (Some(x), Some(y)) => x == y,
        _ => num(a) == num(b),
    }
}

/// The value a coordinate has once written: k / 1000 is the double nearest the decimal k
/// thousandths, which is what parsing the written text gives.
fn q(v: f64) -> f64 {
    match thousandths(v) {
        Some(k) => k as f64 / 1000.0,
        None => num(v).parse().unwrap_or(v),
    }
}

/// A feed, speed or time: up to three decimals, trailing zeros dropped.
fn short(v: f64) -> String {
    let s = num(v);
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s.is_empty() || s == "-" {
        "0".into()
    } else {
        s.to_string()
    }
}

/// GRBL 1.1's arc check (`gc_execute_line`, in single precision as on the controller):
/// the target must lie on the circle through the start within 0.005 mm, or within 0.1 %
/// of the radius when that is larger (and never more than 0.5 mm off).
pub fn grbl_arc_ok(from: Point, to: Point, ij: Point) -> bool {
    let x = (to.x - from.x) as f32 - ij.x as f32;
    let y = (to.y - from.y) as f32 - ij.y as f32;
    let target_r = x.hypot(y);
    let r = (ij.x as f32).hypot(ij.y as f32);
    let delta = (target_r - r).abs();
    !(delta > 0.005 && (delta > 0.5 || delta > 0.001 * r))
}

struct Writer {
    dialect: Dialect,
    lines: Vec<String>,
    /// The written (rounded) position, per axis, once known.
    pos: [Option<f64>; 3],
    feed: Option<String>,
    /// The thousandths of the feed last written (when `thousandths` gives them).
    feed_thousandths: Option<i64>,
    spindle: Option<f64>,
    moved: bool,
    /// A canned drilling cycle is in force (cancelled with G80 before anything else).
    in_cycle: bool,
}

impl Writer {
    fn push(&mut self, l: String) {
        if self.in_cycle {
            self.in_cycle = false;
            self.lines.push("G80".into());
        }
        self.lines.push(l);
    }

    /// One drilled hole as a canned cycle (G81, G82, G83; G98: back to the start height).
    fn cycle(&mut self, m: &Move) {
        let &Move::Drill {
            at,
            clear,
            retract,
            bottom,
            peck,
            dwell,
            feed,
        } = m
        else {
            return;
        };
        if self.pos[2].is_none_or(|p| !same_written(p, clear)) {
            let mut l = String::from("G0 Z");
            push_num(&mut l, clear);
            self.push(l);
        }
        let (g, extra) = if peck > 0.0 {
            ("G83", format!(" Q{}", short(peck)))
        } else if dwell > 0.0 {
            ("G82", format!(" P{}", short(dwell)))
        } else {
            ("G81", String::new())
        };
        let mut line = String::with_capacity(48);
        line.push_str("G98 ");
        line.push_str(g);
        for (letter, v) in [(" X", at.x), (" Y", at.y), (" Z", bottom), (" R", retract)] {
            line.push_str(letter);
            push_num(&mut line, v);
        }
        line.push_str(&extra);
        self.feed_word(&mut line, feed);
        self.lines.push(line);
        self.in_cycle = true;
        self.set_pos([at.x, at.y, clear]);
    }

    /// Appends the words of the axes that change (X and Y always with `all_xy`); returns
    /// whether any was written.
    fn axes(&self, line: &mut String, to: [f64; 3], all_xy: bool) -> bool {
        let before = line.len();
        for (k, letter) in ['X', 'Y', 'Z'].into_iter().enumerate() {
            let changed = self.pos[k].is_none_or(|p| !same_written(p, to[k]));
            if changed || (all_xy && k < 2) {
                line.push(' ');
                line.push(letter);
                push_num(line, to[k]);
            }
        }
        line.len() > before
    }

    /// Appends the feed word when the feed written changes.
    fn feed_word(&mut self, line: &mut String, feed: f64) {
        // the same thousandths are the same text: no need to write it out to compare
        let k = thousandths(feed);
        if k.is_some() && self.feed.is_some() && k == self.feed_thousandths {
            return;
        }
        self.feed_thousandths = k;
        let f = short(feed);
        if self.feed.as_deref() != Some(f.as_str()) {
            line.push_str(" F");
            line.push_str(&f);
            self.feed = Some(f);
        }
    }

    fn set_pos(&mut self, to: [f64; 3]) {
        self.pos = [Some(q(to[0])), Some(q(to[1])), Some(q(to[2]))];
        self.moved = true;
    }

    fn rapid(&mut self, to: [f64; 3]) {
        let mut line = String::with_capacity(32);
        line.push_str("G0");
        if self.axes(&mut line, to, false) {
            self.push(line);
        }
        self.set_pos(to);
    }

    fn linear(&mut self, to: [f64; 3], feed: f64) {
        let mut line = String::with_capacity(40);
        line.push_str("G1");
        if self.axes(&mut line, to, false) {
            self.feed_word(&mut line, feed);
            self.push(line);
        }
        self.set_pos(to);
    }

    /// An arc from the written position to `to` about `center`, exact start `from`.
    fn arc(&mut self, from: P3, to: P3, center: Point, ccw: bool, feed: f64) {
        let (Some(ax), Some(ay)) = (self.pos[0], self.pos[1]) else {
            unreachable!("arcs are only written from a known position");
        };
        let a = Point::new(ax, ay);
        let b = Point::new(q(to.x), q(to.y));
        let seg = arc_segment(from.xy(), to.xy(), center, ccw);
        let Some(planned) = PlannedArc::new(&seg) else {
            unreachable!("arc_segment makes an arc");
        };
        let sweep = seg.sweep();
        let r = 0.5 * (from.xy().dist(center) + to.xy().dist(center));
        let chord = a.dist(b);
        let half_turn = std::f64::consts::PI;
        let sagitta = r * (1.0 - (sweep.abs().min(half_turn) / 2.0).cos());
        let straight = r < MIN_ARC_RADIUS
            || (sweep.abs() <= half_turn && sagitta < MAX_SAGITTA_AS_LINE)
            || (chord == 0.0 && sweep.abs() <= half_turn);
        if straight {
            self.linear([to.x, to.y, to.z], feed);
            return;
        }
        // Two starting points for the centre: the planned one, and the point of the written
        // chord's bisector nearest it (as far from both written ends, which GRBL's check
        // wants when the planned end is off the circle). I and J are rounded too: of the
        // written centres on the 0.001 mm grid around both, keep the one whose arc, as
        // GRBL runs it, stays closest to the planned arc and passes GRBL's check.
        // (an array, not a vector: one allocation per arc was a tenth of the post's time)
        let mut bases = [center; 2];
        let mut nbases = 1;
        if chord >= 0.05 {
            let mid = a.lerp(b, 0.5);
            let n = (b - a).unit().perp();
            bases[1] = mid + n * (center - mid).dot(n);
            nbases = 2;
        }
        // the planned centre, rounded, when GRBL takes it and it runs within a micrometre
        // of the plan: on a short arc many centres run about as close, and the planned one
        // keeps the arc's radius as planned
        let planned_ij = Point::new(q(center.x - a.x), q(center.y - a.y));
        let mut best: Option<(f64, Point)> = None;
        if grbl_arc_ok(a, b, planned_ij) && planned_ij.len() >= MIN_ARC_RADIUS {
            // (past 1e-3 it is not taken, wherever the walk stops; nor is the value used
            // once it is taken, so a bound within 1e-3 takes it without the walk)
            let centre = a + planned_ij;
            let dev = match written_arc_bound(a, b, centre, ccw, &planned, sweep) {
                Some(bound) if bound <= 1e-3 => bound,
                _ => written_arc_deviation(a, b, centre, ccw, &planned, 2e-3),
            };
            if dev <= 1e-3 {
                best = Some((dev, planned_ij));
                nbases = 0;
            }
        }
        for &base in &bases[..nbases] {
            let ij0 = Point::new(q(base.x - a.x), q(base.y - a.y));
            for dx in -3..=3 {
                for dy in -3..=3 {
                    let ij = Point::new(q(ij0.x + dx as f64 * 1e-3), q(ij0.y + dy as f64 * 1e-3));
                    if !grbl_arc_ok(a, b, ij) || ij.len() < MIN_ARC_RADIUS {
                        continue;
                    }
                    // a candidate as far as the best so far cannot replace it
                    let cutoff = best.map_or(f64::INFINITY, |(d, _)| d);
                    if written_arc_floor(a, b, a + ij, ccw, &planned) >= cutoff {
                        continue;
                    }
                    let dev = written_arc_deviation(a, b, a + ij, ccw, &planned, cutoff);
                    if best.is_none_or(|(d, _)| dev < d) {
                        best = Some((dev, ij));
                    }
                }
            }
        }
        let ij = match best {
            Some((dev, ij)) if dev <= MAX_ARC_DEVIATION => ij,
            _ => {
                // an arc whose ends are not on one circle: follow it with short lines
                self.flatten(from, to, center, ccw, feed);
                return;
            }
        };
        let mut line = String::with_capacity(56);
        line.push_str(if ccw { "G3 X" } else { "G2 X" });
        push_num(&mut line, b.x);
        line.push_str(" Y");
        push_num(&mut line, b.y);
        if self.pos[2].is_none_or(|p| !same_written(p, to.z)) {
            line.push_str(" Z");
            push_num(&mut line, to.z);
        }
        line.push_str(" I");
        push_num(&mut line, ij.x);
        line.push_str(" J");
        push_num(&mut line, ij.y);
        self.feed_word(&mut line, feed);
        self.push(line);
        self.set_pos([to.x, to.y, to.z]);
    }

    fn flatten(&mut self, from: P3, to: P3, center: Point, ccw: bool, feed: f64) {
        let seg = arc_segment(from.xy(), to.xy(), center, ccw);
        let r = from.xy().dist(center).max(1e-9);
        let step = 2.0 * (1.0 - MAX_SAGITTA_AS_LINE / r).clamp(-1.0, 1.0).acos();
        let n = ((seg.sweep().abs() / step.max(1e-6)).ceil() as usize).clamp(1, 100_000);
        for i in 1..=n {
            let t = i as f64 / n as f64;
            let p = if i == n { to.xy() } else { seg.point_at(t) };
            self.linear([p.x, p.y, from.z + (to.z - from.z) * t], feed);
        }
    }
}

fn check_extra(place: &'static str, l: &str, dialect: Dialect) -> Result<(), GcodeError> {
    let bad = |why| {
        Err(GcodeError::BadExtraLine {
            place,
            text: l.to_string(),
            why,
        })
    };
    if !l.is_ascii() || l.bytes().any(|b| b < b' ') {
        return bad("it holds control characters or bytes beyond ASCII");
    }
    if dialect == Dialect::Grbl {
        if l.len() > GRBL_MAX_LINE {
            return bad("it is longer than GRBL's 80 characters");
        }
        if l.contains(['(', ';', '?', '!', '~']) {
            return bad("GRBL takes no comments and acts on ? ! ~ at once");
        }
    }
    Ok(())
}

fn envelope_check(index: usize, p: [f64; 3], opts: &GcodeOptions) -> Result<(), GcodeError> {
    for (k, axis) in ['X', 'Y', 'Z'].into_iter().enumerate() {
        if let Some(min) = opts.envelope_min {
            if p[k] < min[k] - 1e-9 {
                return Err(GcodeError::OutsideEnvelope {
                    index,
                    axis,
                    value: p[k],
                    limit: min[k],
                    side: "minimum",
                });
            }
        }
        if let Some(max) = opts.envelope_max {
            if p[k] > max[k] + 1e-9 {
                return Err(GcodeError::OutsideEnvelope {
                    index,
                    axis,
                    value: p[k],
                    limit: max[k],
                    side: "maximum",
                });
            }
        }
    }
    Ok(())
}

/// Checks every move before anything is written: finite numbers, feeds, sewing moves,
/// arcs from a known position, the work envelope.
fn validate(tp: &Toolpath, opts: &GcodeOptions) -> Result<(), GcodeError> {
    let mut known_xy = false;
    let mut pos = P3::default();
    for (index, m) in tp.moves.iter().enumerate() {
        let finite = |vals: &[f64]| {
            if vals.iter().all(|v| v.is_finite()) {
                Ok(())
            } else {
                Err(GcodeError::NotFinite { index })
            }
        };
        match m {
            Move::Rapid { to } => {
                finite(&[to.x, to.y, to.z])?;
                envelope_check(index, [to.x, to.y, to.z], opts)?;
                known_xy = true;
                pos = *to;
            }
            Move::Linear { to, feed } => {
                finite(&[to.x, to.y, to.z, *feed])?;
                if *feed <= 0.0 {
                    return Err(GcodeError::BadFeed { index, feed: *feed });
                }
                envelope_check(index, [to.x, to.y, to.z], opts)?;
                known_xy = true;
                pos = *to;
            }
            Move::Arc {
                to,
                center,
                ccw,
                feed,
            } => {
                finite(&[to.x, to.y, to.z, center.x, center.y, *feed])?;
                if *feed <= 0.0 {
                    return Err(GcodeError::BadFeed { index, feed: *feed });
                }
                if !known_xy {
                    return Err(GcodeError::UnknownStart { index });
                }
                envelope_check(index, [to.x, to.y, to.z], opts)?;
                // the arc's extremes matter only where there is an envelope
                if opts.envelope_min.is_some() || opts.envelope_max.is_some() {
                    let b = arc_segment(pos.xy(), to.xy(), *center, *ccw).bounds();
                    let zlo = pos.z.min(to.z);
                    let zhi = pos.z.max(to.z);
                    envelope_check(index, [b.min.x, b.min.y, zlo], opts)?;
                    envelope_check(index, [b.max.x, b.max.y, zhi], opts)?;
                }
                pos = *to;
            }
            Move::Stitch { .. } => {
                return Err(GcodeError::SewingMove {
                    index,
                    what: "stitch",
                })
            }
            Move::Jump { .. } => {
                return Err(GcodeError::SewingMove {
                    index,
                    what: "jump",
                })
            }
            Move::Trim => {
                return Err(GcodeError::SewingMove {
                    index,
                    what: "trim",
                })
            }
            Move::ColorChange => {
                return Err(GcodeError::SewingMove {
                    index,
                    what: "colour change",
                })
            }
            Move::Spindle { rpm } => {
                finite(&[*rpm])?;
            }
            Move::Dwell { seconds } => finite(&[*seconds])?,
            Move::Drill {
                at,
                clear,
                retract,
                bottom,
                peck,
                dwell,
                feed,
            } => {
                finite(&[at.x, at.y, *clear, *retract, *bottom, *peck, *dwell, *feed])?;
                if *feed <= 0.0 {
                    return Err(GcodeError::BadFeed { index, feed: *feed });
                }
                if !(bottom < retract && retract <= clear) {
                    return Err(GcodeError::BadDrill {
                        index,
                        clear: *clear,
                        retract: *retract,
                        bottom: *bottom,
                    });
                }
                envelope_check(index, [at.x, at.y, *clear], opts)?;
                envelope_check(index, [at.x, at.y, *bottom], opts)?;
                known_xy = true;
                pos = P3::at_z(*at, *clear);
            }
            Move::ProbeToolLength {
                at,
                clear,
                lowest,
                feed,
                thickness,
            } => {
                finite(&[at.x, at.y, *clear, *lowest, *feed, *thickness])?;
                if *feed <= 0.0 {
                    return Err(GcodeError::BadFeed { index, feed: *feed });
                }
                envelope_check(index, [at.x, at.y, *clear], opts)?;
                envelope_check(index, [at.x, at.y, *lowest], opts)?;
                known_xy = true;
                pos = P3::at_z(*at, *clear);
            }
            Move::Stop | Move::ToolChange { .. } | Move::Comment { .. } => {}
        }
    }
    Ok(())
}

/// The height of the retracts before the first move and after the last.
fn safe_height(tp: &Toolpath, opts: &GcodeOptions) -> Option<f64> {
    opts.safe_z.or_else(|| {
        let mut top: Option<f64> = None;
        tp.walk(P3::default(), |_, _, to| {
            top = Some(top.map_or(to.z, |t: f64| t.max(to.z)));
        });
        top
    })
}

/// GRBL's tool change: a program stop whose comment names the tool to load (GRBL 1.1 drops
/// comments as it reads a line), `M0 (load T2: 6 mm flat end mill)`, within 80 characters.
fn tool_stop_line(tool: u32, name: &str) -> String {
    // GRBL acts on ? ! ~ wherever they come, comments too: nothing but plain words
    let clean: String = name
        .chars()
        .map(|c| match c {
            '(' | ')' | '?' | '!' | '~' | ';' => ' ',
            c if c.is_ascii_graphic() || c == ' ' => c,
            _ => '_',
        })
        .collect();
    let clean = clean.trim();
    let head = format!("M0 (load T{tool}");
    if clean.is_empty() {
        return format!("{head})");
    }
    let room = GRBL_MAX_LINE - head.len() - 3;
    let name: String = clean.chars().take(room).collect();
    format!("{head}: {})", name.trim_end())
}

/// The tool a program stop line written by the GRBL post asks the operator to load: its
/// number and name (`M0 (load T2: 6 mm flat end mill)` → 2, "6 mm flat end mill").
pub fn tool_to_load(line: &str) -> Option<(u32, String)> {
    let Some(rest) = line
        .strip_prefix("M0 (load T")
        .and_then(|r| r.strip_suffix(')'))
    else {
        // a tool change as other CAM programs write it for a controller that takes M6
        // (`T1 M6`, `N35 M6 T1`): the tool's number, its name from the machine's table
        return tool_change_of(line).map(|n| (n, String::new()));
    };
    let (n, name) = match rest.split_once(':') {
        Some((n, name)) => (n, name.trim()),
        None => (rest, ""),
    };
    Some((n.trim().parse().ok()?, name.to_string()))
}

/// The tool an `M6` line loads by the `T` word on the same line (`T1 M6`, `N35 M6 T1`), or
/// None for any other line.
pub fn tool_change_of(line: &str) -> Option<u32> {
    if !line.contains('6') {
        return None;
    }
    let words = crate::gcode_read::words(&crate::gcode_read::clean(line));
    let m6 = words
        .iter()
        .any(|(l, v)| *l == 'M' && v.parse::<f64>().ok() == Some(6.0));
    let t = words
        .iter()
        .find(|(l, _)| *l == 'T')
        .and_then(|(_, v)| v.parse::<u32>().ok());
    t.filter(|_| m6)
}

fn comment(text: &str) -> String {
    let clean: String = text
        .chars()
        .map(|c| match c {
            '(' | ')' => ' ',
            c if c.is_ascii() && !c.is_ascii_control() => c,
            _ => '?',
        })
        .collect();
    format!("({})", clean.trim())
}

/// The G-code post of one dialect: units are lines, the file is the lines.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GcodePost(pub Dialect);

impl Post for GcodePost {
    type Unit = String;
    fn name(&self) -> &'static str {
        match self.0 {
            Dialect::Grbl => "grbl",
            Dialect::Linuxcnc => "linuxcnc",
            Dialect::Generic => "generic",
        }
    }
    fn about(&self) -> &'static str {
        match self.0 {
            Dialect::Grbl => "G-code for GRBL 1.1 / grblHAL (no comments, lines of at most 80 characters, arcs that pass error:33)",
            Dialect::Linuxcnc => "G-code for LinuxCNC (tool changes with M6, comments)",
            Dialect::Generic => "plain G-code (G0-G3, G17, G21, G90, G94, M3/M5, M6)",
        }
    }
    fn extension(&self) -> &'static str {
        match self.0 {
            Dialect::Linuxcnc => "ngc",
            _ => "nc",
        }
    }
    fn units(&self, tp: &Toolpath) -> Result<Vec<String>, PostError> {
        let opts = GcodeOptions {
            dialect: self.0,
            ..Default::default()
        };
        post(tp, &opts).map_err(|e| PostError::new(self.name(), e))
    }
    fn file(&self, lines: &[String], _label: &str) -> Result<Vec<u8>, PostError> {
        Ok(lines_file(lines))
    }
}

/// Turns a tool path into G-code lines for the dialect.
pub fn post(tp: &Toolpath, opts: &GcodeOptions) -> Result<Vec<String>, GcodeError> {
    for l in &opts.header {
        check_extra("header", l, opts.dialect)?;
    }
    for l in &opts.footer {
        check_extra("footer", l, opts.dialect)?;
    }
    validate(tp, opts)?;
    let safe = safe_height(tp, opts);
    if let Some(z) = safe {
        if !z.is_finite() {
            return Err(GcodeError::NotFinite { index: 0 });
        }
        if let Some(min) = opts.envelope_min {
            if z < min[2] {
                return Err(GcodeError::SafeZOutsideEnvelope {
                    value: z,
                    limit: min[2],
                    side: "minimum",
                });
            }
        }
        if let Some(max) = opts.envelope_max {
            if z > max[2] {
                return Err(GcodeError::SafeZOutsideEnvelope {
                    value: z,
                    limit: max[2],
                    side: "maximum",
                });
            }
        }
    }
    let grbl = opts.dialect == Dialect::Grbl;
    let mut w = Writer {
        dialect: opts.dialect,
        lines: Vec::new(),
        pos: [None; 3],
        feed: None,
        feed_thousandths: None,
        spindle: None,
        moved: false,
        in_cycle: false,
    };
    if !grbl {
        let what = if tp.source.is_empty() {
            tp.operation.clone()
        } else {
            format!("{} of {}", tp.operation, tp.source)
        };
        w.push(comment(&format!("machlink: {what}")));
    }
    w.push(match opts.dialect {
        Dialect::Linuxcnc => "G21 G90 G17 G94 G40 G49 G80".to_string(),
        _ => "G21 G90 G17 G94".to_string(),
    });
    w.lines.extend(opts.header.iter().cloned());
    // a path that loads its own first tool says so with a tool change of its own
    let loads_first = tp
        .moves
        .iter()
        .find(|m| !matches!(m, Move::Comment { .. }))
        .is_some_and(|m| matches!(m, Move::ToolChange { .. }));
    if let (false, Some(tool), false) = (grbl, tp.tool, loads_first) {
        w.push(format!("T{} M6", tool.number));
    }
    if let Some(z) = safe {
        w.push(format!("G0 Z{}", num(z)));
        w.pos[2] = Some(q(z));
    }
    let mut exact = P3::default();
    for m in &tp.moves {
        if let Move::Drill { at, clear, .. } = m {
            if grbl {
                // no canned cycles: the same pecks and retracts as rapids and lines
                let from = P3::new(exact.x, exact.y, w.pos[2].unwrap_or(exact.z));
                for d in m.drill_moves(from) {
                    match d {
                        Move::Rapid { to } => w.rapid([to.x, to.y, to.z]),
                        Move::Linear { to, feed } => w.linear([to.x, to.y, to.z], feed),
                        Move::Dwell { seconds } => w.push(format!("G4 P{}", short(seconds))),
                        _ => {}
                    }
                }
            } else {
                w.cycle(m);
            }
            exact = P3::at_z(*at, *clear);
            continue;
        }
        match m {
            Move::Rapid { to } => {
                w.rapid([to.x, to.y, to.z]);
                exact = *to;
            }
            Move::Linear { to, feed } => {
                w.linear([to.x, to.y, to.z], *feed);
                exact = *to;
            }
            Move::Arc {
                to,
                center,
                ccw,
                feed,
            } => {
                w.arc(exact, *to, *center, *ccw, *feed);
                exact = *to;
            }
            Move::Spindle { rpm } => {
                if *rpm > 0.0 {
                    w.push(format!("M3 S{}", short(*rpm)));
                    w.spindle = Some(*rpm);
                } else {
                    w.push("M5".into());
                    w.spindle = None;
                }
            }
            Move::Dwell { seconds } => w.push(format!("G4 P{}", short(seconds.max(0.0)))),
            Move::Stop => w.push("M0".into()),
            Move::ToolChange { tool, name, .. } => {
                // the spindle stops for the change; the tool path starts it again (with
                // its spin-up dwell) when it wants it
                if w.spindle.take().is_some() {
                    w.push("M5".into());
                }
                if grbl {
                    w.push(tool_stop_line(*tool, name));
                } else {
                    if !name.is_empty() {
                        w.push(comment(&format!("T{tool}: {name}")));
                    }
                    w.push(format!("T{tool} M6"));
                }
            }
            Move::ProbeToolLength {
                at,
                clear,
                lowest,
                feed,
                thickness,
            } => {
                // up, over the touch plate, down until the tool touches it (G38.2: an alarm
                // if it never does), that height is the plate's top, and back up
                if w.pos[2] != Some(q(*clear)) {
                    // straight up first, wherever the tool is
                    w.push(format!("G0 Z{}", num(*clear)));
                    w.pos[2] = Some(q(*clear));
                }
                w.rapid([at.x, at.y, *clear]);
                w.push(format!("G38.2 Z{} F{}", num(*lowest), short(*feed)));
                w.push(format!("G10 L20 P0 Z{}", num(*thickness)));
                w.pos[2] = Some(q(*thickness));
                // the feed word of the next cut is written again: G38.2 set its own
                w.feed = None;
                w.rapid([at.x, at.y, *clear]);
                exact = P3::at_z(*at, *clear);
            }
            Move::Comment { text } => {
                if !grbl {
                    w.push(comment(text));
                }
            }
            Move::Stitch { .. } | Move::Jump { .. } | Move::Trim | Move::ColorChange => {
                unreachable!("validate() refuses sewing moves")
            }
            Move::Drill { .. } => unreachable!("drilling cycles are written above"),
        }
    }
    if let Some(z) = safe {
        if w.pos[2].is_some_and(|p| p < q(z)) {
            w.push(format!("G0 Z{}", num(z)));
        }
    }
    if w.spindle.is_some() {
        w.push("M5".into());
    }
    w.lines.extend(opts.footer.iter().cloned());
    w.push(if opts.end_with_m30 { "M30" } else { "M2" }.into());
    if w.dialect == Dialect::Grbl {
        for (i, l) in w.lines.iter().enumerate() {
            if l.len() > GRBL_MAX_LINE {
                return Err(GcodeError::LineTooLong {
                    line: i + 1,
                    len: l.len(),
                });
            }
        }
    }
    Ok(w.lines)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// splitmix64: a reproducible stream of uniform numbers in [0, 1)
    fn uniform(state: &mut u64) -> f64 {
        *state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = *state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }

    #[test]
    fn the_closed_form_bounds_hold_the_walked_deviation_between_them() {
        // planned arcs of every size and sweep (short, half and long turns, both ways), the
        // end's radius a little off at times; written ends on the 0.001 mm grid; written
        // centres the planned one rounded, its grid neighbours and centres further off
        let mut state = 25u64;
        let (mut walked_within, mut bound_within) = (0, 0);
        for case in 0..6000 {
            let mut u = || uniform(&mut state);
            let centre = Point::new(400.0 * u() - 200.0, 400.0 * u() - 200.0);
            let radius = 0.02 + 150.0 * u() * u();
            let start = std::f64::consts::TAU * u();
            let sweep = match case % 4 {
                0 => 0.01 + 0.5 * u(),
                1 => std::f64::consts::PI * (0.98 + 0.04 * u()),
                2 => 0.01 + (std::f64::consts::TAU - 0.02) * u(),
                _ => std::f64::consts::TAU - 0.3 * u(),
            };
            let ccw = u() < 0.5;
            let end_angle = if ccw { start + sweep } else { start - sweep };
            let end_radius = if case % 3 == 0 {
                radius + 4e-4 * (u() - 0.5)
            } else {
                radius
            };
            let from = centre + Point::new(start.cos(), start.sin()) * radius;
            let to = centre + Point::new(end_angle.cos(), end_angle.sin()) * end_radius;
            let seg = arc_segment(from, to, centre, ccw);
            let planned = PlannedArc::new(&seg).unwrap();
            let (a, b) = (
                Point::new(q(from.x), q(from.y)),
                Point::new(q(to.x), q(to.y)),
            );
            let ij0 = Point::new(q(centre.x - a.x), q(centre.y - a.y));
            let mut centres = vec![a + ij0];
            for (dx, dy) in [(-1, 0), (1, 0), (0, 1), (0, -1), (2, -3), (-3, 3)] {
                centres.push(a + Point::new(ij0.x + dx as f64 * 1e-3, ij0.y + dy as f64 * 1e-3));
            }
            let far = 0.2 * radius * u();
            centres.push(a + ij0 + Point::new(far * (u() - 0.5), far * (u() - 0.5)));
            for (k, &c) in centres.iter().enumerate() {
                if a.dist(c) < MIN_ARC_RADIUS {
                    continue;
                }
                let walked = written_arc_deviation(a, b, c, ccw, &planned, f64::INFINITY);
                let bound = written_arc_bound(a, b, c, ccw, &planned, seg.sweep());
                if let Some(bound) = bound {
                    assert!(
                        walked <= bound,
                        "case {case}, centre {k}: walked {walked:e} > bound {bound:e} \
                         (planned {centre:?} r {radius} from {from:?} to {to:?} ccw {ccw})"
                    );
                }
                let floor = written_arc_floor(a, b, c, ccw, &planned);
                assert!(
                    floor <= walked,
                    "case {case}, centre {k}: floor {floor:e} > walked {walked:e}"
                );
                if k == 0 && walked <= 1e-3 {
                    walked_within += 1;
                    if bound.is_some_and(|b| b <= 1e-3) {
                        bound_within += 1;
                    }
                }
            }
        }
        // and the bound is worth having: it takes most of the rounded planned centres the
        // walk takes, without the walk
        assert!(
            bound_within * 10 >= walked_within * 7,
            "the bound took {bound_within} of the {walked_within} centres the walk took"
        );
    }

    #[test]
    fn grbl_takes_its_own_g_codes_and_words_and_names_the_rest() {
        let g = Dialect::Grbl;
        for (letter, value) in [
            ('G', "0"),
            ('G', "01"),
            ('G', "28"),
            ('G', "38.2"),
            ('G', "43.1"),
            ('G', "53"),
            ('G', "91.1"),
            ('N', "10"),
            ('T', "1"),
            ('S', "12000"),
            ('R', "-5"),
        ] {
            assert_eq!(g.refuses(letter, value), None, "{letter}{value}");
        }
        for (letter, value, says) in [
            ('G', "81", "G81 (a canned cycle)"),
            ('G', "98", "G98 (a canned cycle's return height)"),
            ('G', "41", "G41 (cutter radius compensation)"),
            ('G', "43", "G43 (a tool length offset"),
            ('G', "64", "G64 (path blending)"),
            ('G', "38.6", "G38.6 is not"),
            ('H', "1", "the word H1 (a tool length offset number)"),
            ('Q', "2", "Q2 (a canned cycle's peck)"),
        ] {
            let e = g.refuses(letter, value).expect(says);
            assert!(e.contains(says) && e.contains("GRBL 1.1"), "{e}");
        }
        // LinuxCNC and the generic dialect: what the reader follows is checked elsewhere
        assert_eq!(Dialect::Linuxcnc.refuses('G', "81"), None);
        assert_eq!(Dialect::Generic.refuses('H', "1"), None);
    }

    fn lines(p: &[String]) -> &[String] {
        p
    }

    #[test]
    fn numbers_are_fixed_without_exponent_or_negative_zero() {
        assert_eq!(num(-0.0001), "0.000");
        assert_eq!(num(-0.0), "0.000");
        assert_eq!(num(1e-12), "0.000");
        assert_eq!(num(123456.78901), "123456.789");
        assert_eq!(num(-2.5), "-2.500");
        assert_eq!(short(1200.0), "1200");
        assert_eq!(short(0.25), "0.25");
    }

    #[test]
    fn the_fixed_decimal_writer_writes_what_the_formatter_writes() {
        // ties and near ties (0.0005, 1.0005, 2.675), negative zero, big and huge values,
        // and a sweep of values on and between the 0.001 mm grid
        let mut vals = vec![
            0.0005,
            -0.0005,
            1.0005,
            2.675,
            -2.675,
            0.0015,
            1e-300,
            -1e-300,
            999.9995,
            2147483.6475,
            -2147483.6485,
            1e9 + 0.1234,
            -3.1e12,
            12345.6785,
            0.1 + 0.2,
        ];
        let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
        for i in 0..200_000 {
            // a xorshift walk over magnitudes from 1e-4 to 1e6
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let m = (x >> 11) as f64 / (1u64 << 53) as f64;
            let v = 10f64.powf(m * 10.0 - 4.0) * if i % 2 == 0 { 1.0 } else { -1.0 };
            vals.push(v);
            vals.push((v * 1000.0).round() / 1000.0 + 0.0005);
        }
        // exact ties (odd sixteenths: 1000 v = 62.5 × odd, held exactly), their neighbours
        // a bit either side, and neighbours of the decimal ties (k + 0.5) / 1000
        let around = |v: f64| {
            let b = v.to_bits();
            [f64::from_bits(b - 1), v, f64::from_bits(b + 1)]
        };
        for j in 1..40_000i64 {
            let t = j as f64 / 16.0;
            vals.extend(around(t));
            vals.extend(around(t).map(|v| -v));
            let d = (2 * j * 7919 % 2_000_000_000 + 1) as f64 / 2000.0;
            vals.extend(around(d));
            vals.extend(around(d).map(|v| -v));
        }
        // up to the writer's own limit (2^53 thousandths, 9e12 mm) and past it, subnormals
        for i in 0..20_000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let m = (x >> 11) as f64 / (1u64 << 53) as f64;
            vals.push(10f64.powf(6.0 + m * 7.5) * if i % 2 == 0 { 1.0 } else { -1.0 });
        }
        vals.extend([
            // about the writer's limit of 2^53 thousandths
            (1u64 << 53) as f64 / 1000.0 - 0.01,
            (1u64 << 53) as f64 / 1000.0,
            -9.1e12,
            1e300,
            f64::MAX,
            f64::MIN_POSITIVE,
            -f64::MIN_POSITIVE / 3.0,
            5e-324,
            -0.0,
            0.0,
        ]);
        for v in vals {
            let s = format!("{v:.3}");
            let want = match s.strip_prefix('-') {
                Some(r) if r.bytes().all(|b| b == b'0' || b == b'.') => r.to_string(),
                _ => s,
            };
            assert_eq!(num(v), want, "{v:e}");
            assert_eq!(q(v), want.parse::<f64>().unwrap(), "{v:e}");
        }
    }

    #[test]
    fn envelope_errors_name_the_move_and_the_coordinate() {
        let mut tp = Toolpath::new("t");
        tp.push(Move::Rapid {
            to: P3::new(0.0, 0.0, 5.0),
        });
        tp.push(Move::Arc {
            to: P3::new(20.0, 0.0, 5.0),
            center: Point::new(10.0, 0.0),
            ccw: true,
            feed: 100.0,
        });
        let opts = GcodeOptions {
            envelope_min: Some([-50.0, -5.0, -10.0]),
            envelope_max: Some([50.0, 50.0, 10.0]),
            ..Default::default()
        };
        // the ccw half circle from (0,0) to (20,0) about (10,0) dips to y = -10
        let e = post(&tp, &opts).unwrap_err();
        assert!(matches!(
            e,
            GcodeError::OutsideEnvelope {
                index: 1,
                axis: 'Y',
                side: "minimum",
                ..
            }
        ));
        assert!(e.to_string().starts_with("move 1 reaches Y=-10.000"), "{e}");
    }

    #[test]
    fn grbl_gets_no_tool_changer_and_no_comments() {
        let mut tp = Toolpath::new("t");
        tp.push(Move::ToolChange {
            tool: 1,
            name: String::new(),
            geometry: None,
        });
        tp.push(Move::Comment {
            text: "début".into(),
        });
        tp.push(Move::Spindle { rpm: 10000.0 });
        tp.push(Move::Rapid {
            to: P3::new(1.0, 1.0, 2.0),
        });
        tp.push(Move::ToolChange {
            tool: 2,
            name: "6 mm flat end mill".into(),
            geometry: None,
        });
        tp.push(Move::Spindle { rpm: 10000.0 });
        let g = post(&tp, &GcodeOptions::default()).unwrap();
        let gl = lines(&g);
        // the one comment GRBL gets names the tool to load at the program stop
        assert!(!gl.iter().any(|l| l.contains("M6") || l.contains("but")));
        assert!(gl.iter().any(|l| l == "M0 (load T1)"), "{gl:?}");
        let stop = gl
            .iter()
            .position(|l| l.starts_with("M0 (load T2"))
            .unwrap();
        assert_eq!(gl[stop], "M0 (load T2: 6 mm flat end mill)");
        assert_eq!(
            tool_to_load(&gl[stop]),
            Some((2, "6 mm flat end mill".into()))
        );
        assert_eq!(gl[stop - 1], "M5");
        assert_eq!(gl[stop + 1], "M3 S10000");
        let lc = post(
            &tp,
            &GcodeOptions {
                dialect: Dialect::Linuxcnc,
                ..Default::default()
            },
        )
        .unwrap();
        assert!(lines(&lc).iter().any(|l| l == "T2 M6"));
        assert!(lines(&lc).iter().all(|l| l.is_ascii()));
    }
}
