//! Large distances in stages. Offsetting closed boundaries with round joins composes: the
//! points at least a + b inside a region are the points at least b inside the points at
//! least a inside it (a disc of radius a + b is a disc of radius a swept by one of radius
//! b), and growing composes alike. So an offset by a distance much larger than the shape's
//! features is made as a short first stage, which resolves the features (a gear's teeth
//! become the arcs about their tips), and the rest from its result.
//!
//! Why: in one stage the raw offset of every turn away from the offset side fans out into
//! a round join |d| × its turn long, and those fans cross each other and the offsets of
//! the turns the other way, which the global stage must then find and prune: for a gear of
//! 10,000 vertices and 500 teeth shrunk by 400 mm the raw offset is about sixty times the
//! perimeter and each tooth's fan crosses those of some sixty teeth. After a first stage
//! the features it resolved are gone, and each following stage is chosen so that its fans
//! add a bounded multiple of the boundary's length, so the crossings stay proportional to
//! the boundary. A later stage's input is smooth but for corners that turn to the offset
//! side, whose swallowtails the raw offset takes apart where it makes them (see
//! `swallowtail`): so a later stage may go much further than the first.

use super::raw::Ends;
use super::seg::Seg;
use std::sync::OnceLock;
use std::time::Instant;

/// A stage's timer, for profiling the stage schedule: with `MACHLINK_OFFSET_STAGES` set in
/// the environment each stage prints its distance, its input's size and its time on
/// stderr (`kernel_case` and the bench inputs show which stage takes the time).
pub(super) struct Timer {
    started: Option<(Instant, usize)>,
}

impl Timer {
    pub(super) fn start(loops: &[(Vec<Seg>, bool)]) -> Timer {
        static ON: OnceLock<bool> = OnceLock::new();
        let on = *ON.get_or_init(|| std::env::var_os("MACHLINK_OFFSET_STAGES").is_some());
        Timer {
            started: on.then(|| (Instant::now(), loops.iter().map(|(s, _)| s.len()).sum())),
        }
    }

    pub(super) fn report(self, what: &str, distance: f64) {
        if let Some((at, segments)) = self.started {
            let ms = at.elapsed().as_secs_f64() * 1e3;
            eprintln!("{what} {distance:.3} mm on {segments} segments: {ms:.3} ms");
        }
    }
}

/// The first stage's fans may add this many times the boundary's length to the raw offset.
const FAN_PER_LENGTH: f64 = 0.5;

/// A later stage's fans may add this many times the boundary's length. A later stage's
/// input is an earlier one's result: arcs joined smoothly, and corners that turn to the
/// offset side, whose swallowtails the raw offset takes apart where it makes them (see
/// `swallowtail`), so its fans cross little that reaches the global stage. Measured on the
/// 10,000-vertex bench gear with ten islands at 20 to 400 mm, interleaved: 8 and 16 cost
/// the same where the rest after the first stage is one stage of either (up to 200 mm),
/// and at 400 mm 16 makes it one stage where 8 makes two (1.88 against 2.02 ms); 0.5, the
/// first stage's, cost twice as much at 200 mm, and 64 a sixth more on the 100,000-vertex
/// gear. The bound stays, so where a swallowtail is not taken apart (a piece not proven)
/// the crossings still grow with the boundary only.
const LATER_FAN_PER_LENGTH: f64 = 16.0;

/// The stage on the input itself goes this share of the step the fans allow. Its fans
/// come from the polyline's corners, and the raw offset's stack resolves the turns toward
/// the offset side locally only while the distance is small against the features: the
/// 10,000-vertex bench gear shrunk by 4 mm prunes without one crossing, by the full step
/// (7.3 mm) the stack gives up on every tooth and the pair-wise prune makes 2,500 bridge
/// arcs and 5,000 runs. After the first stage the convex corners are arcs, which later
/// stages offset concentrically, so they take the whole step. Measured on that gear with
/// ten islands at 20 to 420 mm: 0.45 to 0.6 cost 13 % fewer instructions than the whole
/// step and 15 to 40 % less time, 0.6 the least time (docs/BENCHMARKS.md).
const FIRST_STAGE_SHARE: f64 = 0.6;

/// The distance of a first stage, when offsetting the oriented closed `loops` by `o` (to
/// the left) in one go would make a raw offset more than twice `FAN_PER_LENGTH` times the
/// boundary's length in fans that must cross something (`LATER_FAN_PER_LENGTH` when the
/// loops are an earlier stage's result); None when one stage is as good.
/// `on_input`: the loops are the offset's input, not an earlier stage's result (see
/// `FIRST_STAGE_SHARE`).
///
/// Per loop, the turns away from the offset side make the fans (F) and the turns towards
/// it fold the offset back (C); only min(F, C) of the fans meets a fold (a convex loop
/// grown, or an island grown, has F − C = 2π of fans that cross nothing). `ends`: each
/// loop's length and turns, F and C (`raw::ends_of` to the side of `o`, which measures a
/// corner's turn without trigonometry).
pub(super) fn first_stage(
    loops: &[(Vec<Seg>, bool)],
    ends: &[Ends],
    o: f64,
    on_input: bool,
) -> Option<f64> {
    let side = o.signum();
    let mut length = 0.0;
    let mut crossing_fans = 0.0;
    for ((segs, closed), ends) in loops.iter().zip(ends) {
        if !closed || segs.is_empty() {
            continue;
        }
        length += ends.length;
        crossing_fans += f64::min(ends.away, ends.toward);
    }
    if !(crossing_fans > 0.0 && length > 0.0) {
        return None;
    }
    let fans = if on_input {
        FAN_PER_LENGTH
    } else {
        LATER_FAN_PER_LENGTH
    };
    let step = fans * length / crossing_fans;
    if o.abs() <= 2.0 * step {
        return None;
    }
    let share = if on_input { FIRST_STAGE_SHARE } else { 1.0 };
    Some(share * step * side)
}
