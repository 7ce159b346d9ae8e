//! Biarc fitting: a sampled circle comes back as arcs of its radius (and, offset by the
//! kernel, as arcs of the offset radius), and every fitted curve
//! stays within the tolerance of its input and is tangent-continuous where the input is smooth.

use offset_core::biarc::{fit_points, fit_polyline, BiarcOptions};
use offset_core::geom::{Point, Polyline, Segment};
use offset_core::offset::{offset_polyline, OffsetOptions};
use proptest::prelude::*;
use std::f64::consts::TAU;

fn circle_points(r: f64, n: usize) -> Vec<Point> {
    (0..n)
        .map(|i| {
            let a = TAU * i as f64 / n as f64;
            Point::new(r * a.cos(), r * a.sin())
        })
        .collect()
}

fn arcs_of(pl: &Polyline, radius: f64) {
    for s in pl.segments() {
        match s {
            Segment::Arc {
                center, radius: r, ..
            } => {
                assert!((r - radius).abs() < 1e-6, "radius {r}, want {radius}");
                assert!(center.len() < 1e-6, "centre {center:?}");
            }
            Segment::Line { .. } => panic!("a line in a fitted circle: {s:?}"),
        }
    }
}

#[test]
fn a_sampled_circle_fits_back_to_arcs_of_its_radius() {
    for n in [100, 1000, 10000] {
        for tol in [0.1, 0.01, 0.001] {
            let pts = circle_points(300.0, n);
            let opts = BiarcOptions {
                tolerance: tol,
                ..Default::default()
            };
            let fitted = fit_points(&pts, true, &opts);
            arcs_of(&fitted, 300.0);
            assert!((fitted.area() - std::f64::consts::PI * 90000.0).abs() < 1e-3);
            eprintln!(
                "circle r=300, {n} points, tolerance {tol}: {} moves -> {} arcs",
                n,
                fitted.segment_count()
            );
            assert!(fitted.segment_count() <= 4);
            // the pipeline for offsets: fit the points first, then offset the arcs exactly
            let grown = offset_polyline(
                &fitted,
                50.0,
                &OffsetOptions {
                    tolerance: tol,
                    ..Default::default()
                },
            )
            .unwrap();
            assert_eq!(grown.len(), 1);
            arcs_of(&grown[0], 350.0);
            // and the same through fit_polyline, which reports the saving
            let (_, rep) = fit_polyline(&Polyline::from_points(&pts, true), &opts);
            assert_eq!(rep.segments_in, n);
            assert_eq!(rep.segments_out, fitted.segment_count());
        }
    }
}

/// The curve the points stand for: the biarc spline through them, each neighbour pair
/// joined by the equal-tangent-length biarc between the tangents of the circles through
/// each point and its neighbours (computed here from the circumcentre and the biarc
/// equation, independently of the fitter).
fn input_curve(pts: &[Point], closed: bool) -> Vec<Segment> {
    let n = pts.len();
    let tangent = |k: usize| -> Point {
        if closed {
            circle_tangent(pts[(k + n - 1) % n], pts[k], pts[(k + 1) % n], pts[k])
        } else if k == 0 {
            circle_tangent(pts[0], pts[1], pts[2], pts[0])
        } else if k == n - 1 {
            circle_tangent(pts[n - 3], pts[n - 2], pts[n - 1], pts[n - 1])
        } else {
            circle_tangent(pts[k - 1], pts[k], pts[k + 1], pts[k])
        }
    };
    let arc = |a: Point, t: Point, b: Point| {
        let c = b - a;
        Segment::from_bulge(a, b, (t.cross(c).atan2(t.dot(c)) / 2.0).tan())
    };
    let m = if closed { n } else { n - 1 };
    let mut out = Vec::new();
    for k in 0..m {
        let (p0, p1) = (pts[k], pts[(k + 1) % n]);
        let (t0, t1) = (tangent(k), tangent((k + 1) % n));
        // |p1 - p0 - d (t0 + t1)| = 2d, the smaller positive root
        let v = p1 - p0;
        let t = t0 + t1;
        let (qa, qb, qc) = (t.dot(t) - 4.0, -2.0 * v.dot(t), v.dot(v));
        let d = if qa.abs() < 1e-12 {
            -qc / qb
        } else {
            let r = (qb * qb - 4.0 * qa * qc).sqrt();
            [(-qb + r) / (2.0 * qa), (-qb - r) / (2.0 * qa)]
                .into_iter()
                .filter(|d| *d > 0.0)
                .fold(f64::INFINITY, f64::min)
        };
        if !d.is_finite() {
            out.push(Segment::Line { a: p0, b: p1 });
            continue;
        }
        let (q0, q1) = (p0 + t0 * d, p1 - t1 * d);
        let joint = q0.lerp(q1, 0.5);
        out.push(arc(p0, t0, joint));
        out.push(arc(joint, (q1 - q0).unit(), p1));
    }
    out
}

/// Unit tangent at `at` (one of a, p, b) of the circle through a, p, b, pointing from a to b.
fn circle_tangent(a: Point, p: Point, b: Point, at: Point) -> Point {
    let d = 2.0 * (a.x * (p.y - b.y) + p.x * (b.y - a.y) + b.x * (a.y - p.y));
    let dir = (b - a).unit();
    if d.abs() < 1e-12 {
        return dir;
    }
    let sq = |q: Point| q.dot(q);
    let c = Point::new(
        (sq(a) * (p.y - b.y) + sq(p) * (b.y - a.y) + sq(b) * (a.y - p.y)) / d,
        (sq(a) * (b.x - p.x) + sq(p) * (a.x - b.x) + sq(b) * (p.x - a.x)) / d,
    );
    let t = (at - c).perp().unit();
    // travel direction: the circle's sense from a through p to b
    let ccw = (p - a).cross(b - p) > 0.0;
    if ccw {
        t
    } else {
        -t
    }
}

fn check_fit(pts: &[Point], closed: bool, tol: f64) -> Result<(), TestCaseError> {
    let fitted = fit_points(
        pts,
        closed,
        &BiarcOptions {
            tolerance: tol,
            ..Default::default()
        },
    );
    let input = Polyline::from_points(pts, closed);
    let curve = input_curve(pts, closed);
    let to_curve = |q: Point| {
        curve
            .iter()
            .map(|s| s.distance_to(q))
            .fold(f64::INFINITY, f64::min)
    };
    // every fitted point lies within the tolerance of the input, and the reverse
    for s in fitted.segments() {
        for k in 0..=16 {
            let q = s.point_at(k as f64 / 16.0);
            let d = to_curve(q);
            prop_assert!(
                d <= tol * (1.0 + 1e-6) + 1e-9,
                "fitted point {q:?} is {d} from the input"
            );
        }
    }
    for &p in pts {
        let d = fitted.distance_to(p);
        prop_assert!(
            d <= tol * (1.0 + 1e-6) + 1e-9,
            "input point {p:?} is {d} from the fit"
        );
    }
    // smooth input: consecutive fitted segments meet tangentially
    let segs: Vec<Segment> = fitted.segments().collect();
    let joints = if closed {
        segs.len()
    } else {
        segs.len().saturating_sub(1)
    };
    for i in 0..joints {
        let (a, b) = (segs[i], segs[(i + 1) % segs.len()]);
        let (ta, tb) = (a.tangent_at(1.0), b.tangent_at(0.0));
        let ang = ta.cross(tb).atan2(ta.dot(tb)).abs();
        prop_assert!(ang < 2e-3, "joint {i} turns {ang} rad");
    }
    // at worst one biarc per input segment
    prop_assert!(fitted.segment_count() <= 2 * input.segment_count());
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(16))]
    #[test]
    fn fitted_curves_stay_within_the_tolerance_and_are_smooth(
        amp in 1.0f64..10.0,
        wave in 60.0f64..200.0,
        phase in 0.0f64..TAU,
        n in 200usize..500,
        tol_exp in -3.0f64..-1.0,
    ) {
        let tol = 10f64.powf(tol_exp);
        let len = 300.0;
        let pts: Vec<Point> = (0..n)
            .map(|i| {
                let x = len * i as f64 / (n - 1) as f64;
                Point::new(x, amp * (x * TAU / wave + phase).sin())
            })
            .collect();
        check_fit(&pts, false, tol)?;
    }

    #[test]
    fn fitted_ellipses_stay_within_the_tolerance(
        a in 5.0f64..200.0,
        ratio in 0.3f64..1.0,
        n in 200usize..500,
        tol_exp in -3.0f64..-1.0,
    ) {
        let tol = 10f64.powf(tol_exp);
        let pts: Vec<Point> = (0..n)
            .map(|i| {
                let t = TAU * i as f64 / n as f64;
                Point::new(a * t.cos(), a * ratio * t.sin())
            })
            .collect();
        check_fit(&pts, true, tol)?;
    }
}

#[test]
fn corners_stay_corners() {
    let sq = [
        Point::new(0.0, 0.0),
        Point::new(10.0, 0.0),
        Point::new(10.0, 10.0),
        Point::new(0.0, 10.0),
    ];
    let f = fit_points(&sq, true, &BiarcOptions::default());
    assert_eq!(f.segment_count(), 4);
    assert!(f.vertices.iter().all(|v| v.bulge == 0.0));
}
