//! Properties of stitch paths over random polylines, both ways: every stitch short enough,
//! on the 0.1 mm grid and within tolerance of its curve, every point of the curve within
//! tolerance of a stitch (nothing left unsewn), and a needle drop on every sharp corner. A
//! curve long enough to sew that comes back `Empty` fails.

use offset_core::check::Checker;
use offset_core::geom::{Bounds, Point, Polyline, Segment, Shape, Vertex};
use offset_core::stitch::GRID;
use offset_core::stitch::{on_grid, snap, stitch, StitchError, StitchParams, GRID_SLACK};
use offset_core::toolpath::Move;
use proptest::prelude::*;

/// Needle drops of a tool path in order, and the jumps' lengths.
fn drops_and_jumps(moves: &[Move]) -> (Vec<(Point, bool)>, Vec<f64>) {
    let mut at = Point::default();
    let mut drops = Vec::new();
    let mut jumps = Vec::new();
    for m in moves {
        match m {
            Move::Stitch { to } => {
                drops.push((*to, true));
                at = *to;
            }
            Move::Jump { to } => {
                jumps.push(at.dist(*to));
                drops.push((*to, false));
                at = *to;
            }
            _ => {}
        }
    }
    (drops, jumps)
}

/// The stitches as open polylines, one per run of needle drops between jumps.
fn sewn_polylines(drops: &[(Point, bool)]) -> Vec<Polyline> {
    let mut out = Vec::new();
    let mut cur: Vec<Point> = Vec::new();
    for &(q, sewn) in drops {
        if !sewn {
            if cur.len() > 1 {
                out.push(Polyline::from_points(&cur, false));
            }
            cur.clear();
        }
        cur.push(q);
    }
    if cur.len() > 1 {
        out.push(Polyline::from_points(&cur, false));
    }
    out
}

fn turn(a: &Segment, b: &Segment) -> f64 {
    let (u, v) = (a.tangent_at(1.0), b.tangent_at(0.0));
    u.cross(v).atan2(u.dot(v)).abs().to_degrees()
}

/// Checks every property for one base curve sewn on the line (row 0).
fn check_on_curve(pl: &Polyline, p: &StitchParams) -> Result<(), TestCaseError> {
    let tp = match stitch(&Shape::new(vec![pl.clone()]), p) {
        Ok(tp) => tp,
        // nothing to sew is right only for a curve shorter than one grid step
        Err(StitchError::Empty(_)) if pl.segment_count() == 0 || pl.length() < GRID => {
            return Ok(())
        }
        Err(e) => return Err(TestCaseError::fail(format!("{e} ({pl:?})"))),
    };
    let (drops, jumps) = drops_and_jumps(&tp.moves);
    // the other way: every point of the curve lies within tolerance (plus the grid's
    // rounding) of a stitch
    let seams = Checker::new(&sewn_polylines(&drops));
    for s in pl.segments() {
        let n = ((s.length() / 0.05).ceil() as usize).clamp(1, 100_000);
        for i in 0..=n {
            let q = s.point_at(i as f64 / n as f64);
            let d = seams.distance(q);
            prop_assert!(
                d <= p.tolerance + GRID_SLACK + 1e-9,
                "the curve at {q:?} is left unsewn: the nearest stitch is {d} mm away"
            );
        }
    }
    for j in jumps {
        prop_assert!(j <= p.max_jump + 1e-9, "jump of {j} mm");
    }
    for (q, _) in &drops {
        prop_assert!(on_grid(q.x) && on_grid(q.y), "{q:?} is off the grid");
    }
    let max_len = p.max_stitch.min(p.stitch_length + 2.0 * GRID_SLACK);
    for w in drops.windows(2) {
        let ((a, _), (b, sewn)) = (w[0], w[1]);
        if !sewn {
            continue;
        }
        let len = a.dist(b);
        prop_assert!(len <= max_len + 1e-9, "stitch {a:?}→{b:?} is {len} mm");
        let n = ((len / 0.01).ceil() as usize).max(1);
        for i in 0..=n {
            let q = a.lerp(b, i as f64 / n as f64);
            let d = pl.distance_to(q);
            prop_assert!(
                d <= p.tolerance + 1e-9,
                "stitch {a:?}→{b:?} strays {d} mm from the curve at {q:?}"
            );
        }
    }
    // a needle drop exactly on every sharp corner
    let segs: Vec<Segment> = pl.segments().filter(|s| s.length() > 1e-9).collect();
    let n = segs.len();
    let pairs: Vec<(usize, usize)> = if pl.closed {
        (0..n).map(|i| ((i + n - 1) % n, i)).collect()
    } else {
        (1..n).map(|i| (i - 1, i)).collect()
    };
    for (i, j) in pairs {
        if turn(&segs[i], &segs[j]) > p.corner_angle + 1e-6 {
            let c = snap(segs[j].start());
            prop_assert!(
                drops.iter().any(|(q, sewn)| *sewn && q.dist(c) < 1e-9),
                "no needle drop on the corner at {c:?}"
            );
        }
    }
    Ok(())
}

fn polyline_strategy() -> impl Strategy<Value = Polyline> {
    (
        prop::collection::vec(
            (
                -80.0f64..80.0,
                -80.0f64..80.0,
                prop_oneof![3 => Just(0.0), 2 => -1.2f64..1.2],
            ),
            2..9,
        ),
        any::<bool>(),
    )
        .prop_map(|(vs, closed)| {
            let vertices = vs
                .into_iter()
                .map(|(x, y, b)| Vertex::new(x, y, b))
                .collect();
            Polyline::new(vertices, closed)
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(offset_core::check::proptest_cases(64)))]

    #[test]
    fn random_curves_sew_within_all_limits(
        pl in polyline_strategy(),
        l in 1.0f64..12.7,
        tol in 0.1f64..0.5,
        corner in 5.0f64..90.0,
        bean in any::<bool>(),
        tie in any::<bool>(),
    ) {
        let p = StitchParams {
            stitch_length: l,
            tolerance: tol,
            corner_angle: corner,
            bean,
            tie,
            ..Default::default()
        };
        check_on_curve(&pl, &p)?;
    }
}

#[test]
fn hexagon_corners_each_get_a_needle_drop() {
    let pts: Vec<Point> = (0..6)
        .map(|k| {
            let a = std::f64::consts::PI / 3.0 * k as f64;
            Point::new(20.0 * a.cos() + 0.03, 20.0 * a.sin() - 0.04)
        })
        .collect();
    let pl = Polyline::from_points(&pts, true);
    let p = StitchParams::default();
    check_on_curve(&pl, &p).unwrap();
}

#[test]
fn a_circle_needs_short_enough_chords() {
    // radius 3 mm, L = 12: a 12 mm chord of a 3 mm circle is impossible within 0.2 mm,
    // so the run gets more stitches than ceil(len / L).
    let pl = Polyline::circle(Point::new(0.0, 0.0), 3.0);
    let p = StitchParams {
        stitch_length: 12.0,
        tie: false,
        ..Default::default()
    };
    check_on_curve(&pl, &p).unwrap();
    let tp = stitch(&Shape::new(vec![pl]), &p).unwrap();
    let n = tp
        .moves
        .iter()
        .filter(|m| matches!(m, Move::Stitch { .. }))
        .count();
    assert!(n > 3, "only {n} needle drops around a 3 mm circle");
}

#[test]
fn snapping_does_not_drift_along_a_long_seam() {
    // 0.07 mm steps accumulate: 1000 stitches of 1.07 mm end exactly at the grid point
    // nearest the true end, not 1000 roundings away from it.
    let end = Point::new(1070.0 * 0.999, 3.33);
    let pl = Polyline::from_points(&[Point::new(0.0, 0.0), end], false);
    let p = StitchParams {
        stitch_length: 1.07,
        tie: false,
        ..Default::default()
    };
    let tp = stitch(&Shape::new(vec![pl.clone()]), &p).unwrap();
    let (drops, _) = drops_and_jumps(&tp.moves);
    let last = drops.last().unwrap().0;
    assert!(last.dist(snap(end)) < 1e-9, "{last:?}");
    for (q, _) in drops {
        assert!(pl.distance_to(q) <= GRID_SLACK + 1e-9);
    }
}

#[test]
fn long_jumps_are_split_into_equal_steps() {
    let a = Polyline::from_points(&[Point::new(0.0, 0.0), Point::new(5.0, 0.0)], false);
    let b = Polyline::from_points(&[Point::new(100.0, 50.0), Point::new(105.0, 50.0)], false);
    let p = StitchParams::default();
    let tp = stitch(&Shape::new(vec![a, b]), &p).unwrap();
    let (_, jumps) = drops_and_jumps(&tp.moves);
    let long: Vec<f64> = jumps.iter().copied().filter(|j| *j > 1.0).collect();
    // 107.35 mm from (5,0) to (100,50): 9 steps of ~11.93 mm (ceil(107.35 / 12.1) = 9)
    assert_eq!(long.len(), 9, "{jumps:?}");
    for j in &long {
        assert!((j - long[0]).abs() < 0.15 && *j <= 12.1);
    }
    assert!(tp.moves.iter().any(|m| matches!(m, Move::Trim)));
}

#[test]
fn the_sewing_area_is_checked_and_the_error_names_the_stitch() {
    let pl = Polyline::from_points(&[Point::new(0.0, 0.0), Point::new(50.0, 0.0)], false);
    let p = StitchParams {
        area: Some(Bounds {
            min: Point::new(-10.0, -10.0),
            max: Point::new(40.0, 10.0),
        }),
        ..Default::default()
    };
    let err = stitch(&Shape::new(vec![pl]), &p).unwrap_err();
    let msg = err.to_string();
    assert!(matches!(err, StitchError::OutsideArea { .. }), "{msg}");
    assert!(
        msg.contains("(40.1, 0.0)") || msg.contains("(42.5, 0.0)"),
        "{msg}"
    );
}

#[test]
fn bad_parameters_are_one_sentence() {
    let pl = Polyline::from_points(&[Point::new(0.0, 0.0), Point::new(50.0, 0.0)], false);
    for p in [
        StitchParams {
            stitch_length: 0.5,
            ..Default::default()
        },
        StitchParams {
            stitch_length: 13.0,
            ..Default::default()
        },
        StitchParams {
            tolerance: 0.05,
            ..Default::default()
        },
        StitchParams {
            rows: vec![],
            ..Default::default()
        },
    ] {
        let e = stitch(&Shape::new(vec![pl.clone()]), &p).unwrap_err();
        assert!(matches!(e, StitchError::BadParam(_)), "{e}");
    }
}
