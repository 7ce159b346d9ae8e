//! How long a program takes on the machine, for the ETA every kind shows: the time of each
//! move at its feed (rapids at a rapid rate, dwells as long as they last), summed. One
//! place for the rule, so G-code lines, Modbus blocks and CANopen set-points agree; a
//! machine's acceleration is left out (an estimate, not a simulation).

use offset_core::{Move, P3};

/// The rapid rate assumed for estimates, mm/min (GRBL's default `$110` is 500; routers run
/// 3000 to 10000).
pub const RAPID: f64 = 3000.0;

/// Stitches per minute assumed for a sewing machine whose config does not say.
pub const SPM: f64 = 600.0;

/// The time of move `m` from `from`, s, and where it ends; `rapid` is the rapid rate in
/// mm/min. Moves that go nowhere (spindle, comments) take no time and end at `from`.
pub fn move_seconds(from: P3, m: &Move, rapid: f64) -> (f64, P3) {
    match m {
        Move::Rapid { to } => (from.dist(*to) / rapid.max(1e-3) * 60.0, *to),
        Move::Linear { to, feed } => (from.dist(*to) / feed.max(1e-3) * 60.0, *to),
        Move::Arc {
            to,
            center,
            ccw,
            feed,
        } => {
            let xy = offset_core::toolpath::arc_segment(from.xy(), to.xy(), *center, *ccw).length();
            (xy.hypot(to.z - from.z) / feed.max(1e-3) * 60.0, *to)
        }
        Move::Dwell { seconds } => (seconds.max(0.0), from),
        _ => (0.0, from),
    }
}

/// The time of `moves` one after the other from the origin, s.
pub fn moves_seconds<'a>(moves: impl IntoIterator<Item = &'a Move>, rapid: f64) -> f64 {
    let (mut t, mut pos) = (0.0, P3::default());
    for m in moves {
        let (dt, to) = move_seconds(pos, m, rapid);
        t += dt;
        pos = to;
    }
    t
}

/// The time of Modbus motion blocks one after the other, s (their targets in µm, feeds
/// in mm/min × 1000, dwells in ms; rapids at `rapid` mm/min).
pub fn blocks_seconds(blocks: &[crate::modbus::MotionBlock], rapid: f64) -> f64 {
    use crate::modbus::BlockKind;
    let mm = |v: i32| v as f64 / 1000.0;
    let (mut t, mut pos) = (0.0, P3::default());
    for b in blocks {
        let to = P3::new(mm(b.target[0]), mm(b.target[1]), mm(b.target[2]));
        let feed = b.feed as f64 / 1000.0;
        let m = match b.kind {
            BlockKind::Rapid => Move::Rapid { to },
            BlockKind::Linear => Move::Linear { to, feed },
            BlockKind::ArcCw | BlockKind::ArcCcw => Move::Arc {
                to,
                center: pos.xy() + offset_core::Point::new(mm(b.center[0]), mm(b.center[1])),
                ccw: b.kind == BlockKind::ArcCcw,
                feed,
            },
            BlockKind::Dwell => Move::Dwell {
                seconds: b.feed as f64 / 1000.0,
            },
            BlockKind::End | BlockKind::ToolChange => continue,
        };
        let (dt, end) = move_seconds(pos, &m, rapid);
        t += dt;
        pos = end;
    }
    t
}

/// The time of `stitches` stitch records at `spm` stitches per minute, s.
pub fn stitches_seconds(stitches: usize, spm: f64) -> f64 {
    stitches as f64 / spm.max(1e-3) * 60.0
}
