//! Flattening: every chord stays within the tolerance of the true curve, and circular arcs stay arcs.

use offset_core::check::Checker;
use offset_core::flatten::{cubic, elliptical_arc, nurbs, quadratic};
use offset_core::geom::{Point, Polyline, Segment};
use proptest::prelude::*;
use std::f64::consts::{FRAC_1_SQRT_2, PI, TAU};

/// Largest distance from the curve (sampled densely) to the polyline, and from the
/// polyline's points to the curve (exact distances to segments, through the checker's
/// index: each sample's search bounded by the one before).
fn deviation(curve: &dyn Fn(f64) -> Point, pts: &[Point]) -> f64 {
    let farthest = |to: &Polyline, from: &mut dyn Iterator<Item = Point>| {
        let c = Checker::new(std::slice::from_ref(to));
        let mut near = None;
        from.map(|p| {
            let d = c.distance_near(p, near);
            near = Some((p, d));
            d
        })
        .fold(0.0, f64::max)
    };
    let pl = Polyline::from_points(pts, false);
    let dense: Vec<Point> = (0..=4000).map(|i| curve(i as f64 / 4000.0)).collect();
    let curve_pl = Polyline::from_points(&dense, false);
    let a = farthest(&pl, &mut dense.iter().copied());
    // chord midpoints against the curve
    let b = farthest(&curve_pl, &mut pts.windows(2).map(|w| w[0].lerp(w[1], 0.5)));
    a.max(b)
}

fn pt() -> impl Strategy<Value = Point> {
    (-100.0f64..100.0, -100.0f64..100.0).prop_map(|(x, y)| Point::new(x, y))
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(offset_core::check::proptest_cases(32)))]
    #[test]
    fn beziers_stay_within_the_tolerance(p0 in pt(), p1 in pt(), p2 in pt(), p3 in pt(), e in -3.0f64..-1.0) {
        let tol = 10f64.powf(e);
        let c = |t: f64| {
            let u = 1.0 - t;
            p0 * (u * u * u) + p1 * (3.0 * u * u * t) + p2 * (3.0 * u * t * t) + p3 * (t * t * t)
        };
        let pts = cubic(p0, p1, p2, p3, tol).unwrap();
        prop_assert!(pts[0] == p0 && *pts.last().unwrap() == p3);
        // the dense reference itself is a polyline: allow its own chord error
        let d = deviation(&c, &pts);
        prop_assert!(d <= tol * 1.01 + 1e-4, "cubic off by {d}, tolerance {tol}, {} points", pts.len());
        let q = |t: f64| {
            let u = 1.0 - t;
            p0 * (u * u) + p1 * (2.0 * u * t) + p2 * (t * t)
        };
        let pts = quadratic(p0, p1, p2, tol).unwrap();
        prop_assert!(deviation(&q, &pts) <= tol * 1.01 + 1e-4);
    }

    #[test]
    fn ellipses_stay_within_the_tolerance(a in 1.0f64..100.0, ratio in 0.1f64..0.99, rot in 0.0f64..TAU, t0 in 0.0f64..TAU, span in 0.1f64..TAU, e in -3.0f64..-1.0) {
        let tol = 10f64.powf(e);
        let major = Point::new(a * rot.cos(), a * rot.sin());
        let c = Point::new(3.0, -2.0);
        let v = elliptical_arc(c, major, ratio, t0, t0 + span, tol).unwrap();
        let pts: Vec<Point> = v.iter().map(|v| v.pos()).collect();
        let minor = major.perp() * ratio;
        let curve = |s: f64| { let t = t0 + span * s; c + major * t.cos() + minor * t.sin() };
        prop_assert!(v.iter().all(|v| v.bulge == 0.0));
        prop_assert!(deviation(&curve, &pts) <= tol * 1.01 + 1e-4);
    }
}

#[test]
fn a_circular_elliptical_arc_is_bulge_arcs() {
    let v = elliptical_arc(
        Point::new(0.0, 0.0),
        Point::new(0.0, 7.0),
        1.0,
        0.0,
        PI * 1.5,
        0.01,
    )
    .unwrap();
    let pl = Polyline::new(v, false);
    assert!(pl.segment_count() >= 3);
    for s in pl.segments() {
        match s {
            Segment::Arc {
                center,
                radius,
                ccw,
                ..
            } => {
                assert!(center.len() < 1e-12 && (radius - 7.0).abs() < 1e-12 && ccw)
            }
            _ => panic!("{s:?}"),
        }
    }
    assert!((pl.length() - 7.0 * 1.5 * PI).abs() < 1e-9);
}

#[test]
fn a_rational_nurbs_quarter_circle_lies_on_the_circle() {
    // the classic exact quarter circle: degree 2, weights 1, 1/√2, 1
    let ctrl = [
        Point::new(10.0, 0.0),
        Point::new(10.0, 10.0),
        Point::new(0.0, 10.0),
    ];
    let knots = [0.0, 0.0, 0.0, 1.0, 1.0, 1.0];
    let w = [1.0, FRAC_1_SQRT_2, 1.0];
    let tol = 1e-3;
    let pts = nurbs(2, &knots, &ctrl, &w, tol).unwrap();
    assert!(pts[0].dist(ctrl[0]) < 1e-12 && pts.last().unwrap().dist(ctrl[2]) < 1e-12);
    for p in &pts {
        assert!((p.len() - 10.0).abs() < 1e-9, "{p:?}");
    }
    // chords within the tolerance: sagitta of each chord on a radius-10 circle
    for w in pts.windows(2) {
        let c = w[0].dist(w[1]);
        assert!(10.0 - (100.0 - c * c / 4.0).sqrt() <= tol);
    }
    // bad data is refused, not a panic
    assert!(nurbs(2, &knots[..5], &ctrl, &w, tol).is_err());
    assert!(nurbs(2, &knots, &ctrl, &[1.0, -1.0, 1.0], tol).is_err());
    assert!(nurbs(0, &knots, &ctrl, &[], tol).is_err());
}

#[test]
fn sweeps_wrap_and_what_cannot_be_flattened_is_refused() {
    use offset_core::flatten::{FlattenError, MAX_POINTS};
    let (c, major) = (Point::new(0.0, 0.0), Point::new(4.0, 0.0));
    let end = |t0: f64, t1: f64| {
        let v = elliptical_arc(c, major, 0.5, t0, t1, 1e-3).unwrap();
        (
            v[0].pos(),
            v[v.len() - 1].pos(),
            Polyline::new(v, false).length(),
        )
    };
    // two turns and a quarter is a quarter; an end before the start wraps once; equal ends
    // (or two whole turns) are the whole ellipse
    let quarter = end(0.0, PI / 2.0);
    let (a, b, l) = end(0.0, 4.0 * PI + PI / 2.0);
    assert!(a.dist(quarter.0) < 1e-9 && b.dist(quarter.1) < 1e-9 && (l - quarter.2).abs() < 1e-6);
    let (_, b, l) = end(PI / 2.0, 0.0);
    assert!(b.dist(Point::new(4.0, 0.0)) < 1e-9 && (l - 3.0 * quarter.2).abs() < 1e-3);
    for t1 in [1.0, 4.0 * PI + 1.0] {
        let (a, b, l) = end(1.0, t1);
        assert!(
            a.dist(b) < 1e-9 && (l - 4.0 * quarter.2).abs() < 1e-3,
            "{t1}"
        );
    }
    // a parameter so large that 2π is lost in its rounding
    assert_eq!(
        elliptical_arc(c, major, 0.5, 0.0, 6.3e86, 1e-3),
        Err(FlattenError::AngleOutOfRange(6.3e86))
    );
    assert!(elliptical_arc(c, major, 0.5, f64::NAN, 1.0, 1e-3).is_err());
    // a curve that would take more points than allowed, rather than a coarse one
    let big = 1e12;
    let r = cubic(
        Point::new(0.0, 0.0),
        Point::new(big, big),
        Point::new(2.0 * big, -big),
        Point::new(3.0 * big, 0.0),
        1e-3,
    );
    assert!(
        matches!(r, Err(FlattenError::TooManyPoints { .. })),
        "{r:?}"
    );
    let n = cubic(
        Point::new(0.0, 0.0),
        Point::new(1e4, 1e4),
        Point::new(2e4, -1e4),
        Point::new(3e4, 0.0),
        1e-3,
    )
    .unwrap()
    .len();
    assert!(n > 100 && n < MAX_POINTS, "{n}");
}
