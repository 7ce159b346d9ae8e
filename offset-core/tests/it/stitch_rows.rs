//! Offset seams: rows sewn at distances inside, outside, left or right of a base curve,
//! checked against the distance to the base curve and against the kernel's offset curves.

use offset_core::geom::{Point, Polyline, Segment, Shape};
use offset_core::offset::{offset_polyline, Join, OffsetOptions};
use offset_core::stitch::{on_grid, snap, stitch, StitchParams, GRID_SLACK};
use offset_core::toolpath::Move;
use proptest::prelude::*;

/// The seams of a tool path: runs of needle drops between jumps.
fn seams(moves: &[Move]) -> Vec<Vec<Point>> {
    let mut out: Vec<Vec<Point>> = vec![];
    let mut cur: Vec<Point> = vec![];
    for m in moves {
        match m {
            Move::Stitch { to } => cur.push(*to),
            Move::Jump { .. } | Move::Trim if !cur.is_empty() => out.push(std::mem::take(&mut cur)),
            _ => {}
        }
    }
    if !cur.is_empty() {
        out.push(cur);
    }
    out
}

/// Every point of every stitch (sampled every 0.01 mm) passes `ok`.
fn each_stitch_point(seam: &[Point], mut ok: impl FnMut(Point) -> bool) -> bool {
    seam.windows(2).all(|w| {
        let n = ((w[0].dist(w[1]) / 0.01).ceil() as usize).max(1);
        (0..=n).all(|i| ok(w[0].lerp(w[1], i as f64 / n as f64)))
    })
}

fn hexagon(r: f64) -> Polyline {
    let pts: Vec<Point> = (0..6)
        .map(|k| {
            let a = std::f64::consts::PI / 3.0 * k as f64;
            Point::new(r * a.cos(), r * a.sin())
        })
        .collect();
    Polyline::from_points(&pts, true)
}

#[test]
fn jeans_pocket_outline_and_a_second_row_3mm_inside() {
    let pocket = Polyline::from_points(
        &[
            Point::new(0.0, 0.0),
            Point::new(140.0, 0.0),
            Point::new(140.0, 120.0),
            Point::new(70.0, 150.0),
            Point::new(0.0, 120.0),
        ],
        true,
    );
    let p = StitchParams {
        rows: vec![0.0, -3.0],
        ..Default::default()
    };
    let tp = stitch(&Shape::new(vec![pocket.clone()]), &p).unwrap();
    let s = seams(&tp.moves);
    assert_eq!(s.len(), 2);
    assert!(each_stitch_point(&s[0], |q| pocket.distance_to(q) <= p.tolerance));
    // the inner row: 3 mm from the outline (corners are mitered, so up to 3 / sin(θ/2)
    // at a corner; the sharpest corner here is the point at the top, 113.4°)
    let far = 3.0 / (113.4f64.to_radians() / 2.0).sin();
    assert!(each_stitch_point(&s[1], |q| {
        let d = pocket.distance_to(q);
        pocket.contains(q) && d >= 3.0 - p.tolerance && d <= far + p.tolerance
    }));
    // and its five corners each get a needle drop: the inner pocket's corners at (3, 3),
    // (137, 3), ...
    for c in [Point::new(3.0, 3.0), Point::new(137.0, 3.0)] {
        assert!(
            s[1].iter().any(|q| q.dist(snap(c)) < 1e-9),
            "no needle drop on the inner corner {c:?}"
        );
    }
}

#[test]
fn hexagon_label_sewn_2mm_inside_keeps_its_corners() {
    let label = hexagon(25.0);
    let p = StitchParams {
        rows: vec![-2.0],
        ..Default::default()
    };
    let tp = stitch(&Shape::new(vec![label.clone()]), &p).unwrap();
    let s = seams(&tp.moves);
    assert_eq!(s.len(), 1);
    assert!(each_stitch_point(&s[0], |q| {
        label.contains(q) && (label.distance_to(q) - 2.0).abs() <= p.tolerance
    }));
    // the inner hexagon's corners lie 2 / cos(30°) nearer the centre
    let r = 25.0 - 2.0 / (30f64.to_radians()).cos();
    for k in 0..6 {
        let a = std::f64::consts::PI / 3.0 * k as f64;
        let c = snap(Point::new(r * a.cos(), r * a.sin()));
        assert!(
            s[0].iter().any(|q| q.dist(c) < 1e-9),
            "no needle drop on corner {k} at {c:?}"
        );
    }
}

#[test]
fn round_corners_when_asked_keep_every_stitch_at_the_distance() {
    let label = hexagon(25.0);
    for (round, corner_far) in [(true, false), (false, true)] {
        let p = StitchParams {
            rows: vec![2.0],
            round_corners: round,
            ..Default::default()
        };
        let tp = stitch(&Shape::new(vec![label.clone()]), &p).unwrap();
        let s = seams(&tp.moves);
        let mut max_d: f64 = 0.0;
        assert!(each_stitch_point(&s[0], |q| {
            let d = label.distance_to(q);
            max_d = max_d.max(d);
            !label.contains(q) && d >= 2.0 - p.tolerance
        }));
        // mitered corners stand 2 / cos(30°) = 2.31 mm off; round ones stay at 2 mm
        assert_eq!(max_d > 2.0 + p.tolerance, corner_far, "{round}: {max_d}");
    }
}

#[test]
fn open_seam_rows_go_left_and_right() {
    let edge = Polyline::from_points(&[Point::new(0.0, 0.0), Point::new(100.0, 0.0)], false);
    let p = StitchParams {
        rows: vec![5.0, -5.0],
        ..Default::default()
    };
    let tp = stitch(&Shape::new(vec![edge]), &p).unwrap();
    let s = seams(&tp.moves);
    assert_eq!(s.len(), 2);
    assert!(s[0].iter().all(|q| (q.y - 5.0).abs() < 1e-9));
    assert!(s[1].iter().all(|q| (q.y + 5.0).abs() < 1e-9));
}

/// A star-shaped (so simple) polygon around the origin.
fn star_strategy() -> impl Strategy<Value = Polyline> {
    prop::collection::vec((0.0f64..1.0, 15.0f64..60.0), 3..10).prop_map(|v| {
        let n = v.len();
        let pts: Vec<Point> = v
            .iter()
            .enumerate()
            .map(|(i, (jit, r))| {
                let a = (i as f64 + 0.8 * jit) / n as f64 * std::f64::consts::TAU;
                Point::new(r * a.cos(), r * a.sin())
            })
            .collect();
        Polyline::from_points(&pts, true)
    })
}

fn turn(a: &Segment, b: &Segment) -> f64 {
    let (u, v) = (a.tangent_at(1.0), b.tangent_at(0.0));
    u.cross(v).atan2(u.dot(v)).abs().to_degrees()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(offset_core::check::proptest_cases(32)))]

    #[test]
    fn offset_rows_stay_on_the_kernel_curves_with_drops_on_their_corners(
        pl in star_strategy(),
        d in prop_oneof![-4.0f64..-0.5, 0.5f64..4.0],
        l in 1.0f64..6.0,
    ) {
        let p = StitchParams { rows: vec![d], stitch_length: l, ..Default::default() };
        let opts = OffsetOptions { join: Join::Miter, miter_limit: 10.0, tolerance: 0.01 };
        let curves = offset_polyline(&pl, d, &opts).unwrap();
        let curves: Vec<Polyline> = curves.into_iter()
            .filter(|c| c.segment_count() > 0 && c.length() >= 0.1).collect();
        let tp = match stitch(&Shape::new(vec![pl.clone()]), &p) {
            Ok(tp) => tp,
            Err(e) => { prop_assert!(curves.is_empty(), "{e}"); return Ok(()); }
        };
        let near = |q: Point| curves.iter().map(|c| c.distance_to(q)).fold(f64::INFINITY, f64::min);
        let all = seams(&tp.moves);
        prop_assert_eq!(all.len(), curves.len());
        for s in &all {
            for q in s {
                prop_assert!(on_grid(q.x) && on_grid(q.y));
            }
            for w in s.windows(2) {
                prop_assert!(w[0].dist(w[1]) <= l + 2.0 * GRID_SLACK + 1e-9);
            }
            prop_assert!(each_stitch_point(s, |q| near(q) <= p.tolerance + 1e-9));
        }
        // the other way: every point of every row curve is sewn (within tolerance and the
        // grid's rounding of a stitch), so a row or a stretch of one left out fails
        let sewn: Vec<Polyline> = all.iter().filter(|s| s.len() > 1)
            .map(|s| Polyline::from_points(s, false)).collect();
        let sewn = offset_core::check::Checker::new(&sewn);
        for c in &curves {
            for sg in c.segments() {
                let n = ((sg.length() / 0.05).ceil() as usize).clamp(1, 100_000);
                for i in 0..=n {
                    let q = sg.point_at(i as f64 / n as f64);
                    let dd = sewn.distance(q);
                    prop_assert!(dd <= p.tolerance + GRID_SLACK + 1e-9,
                        "the row at {:?} is left unsewn: the nearest stitch is {} mm away", q, dd);
                }
            }
        }
        for c in &curves {
            let segs: Vec<Segment> = c.segments().filter(|s| s.length() > 1e-9).collect();
            let n = segs.len();
            for i in 0..n {
                let prev = &segs[(i + n - 1) % n];
                if turn(prev, &segs[i]) > p.corner_angle + 1e-6 {
                    let k = snap(segs[i].start());
                    prop_assert!(all.iter().flatten().any(|q| q.dist(k) < 1e-9),
                        "no needle drop on the offset corner {:?}", k);
                }
            }
        }
    }
}
