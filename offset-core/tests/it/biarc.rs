//! Biarc fitting: the fit stays within the tolerance of the polyline it was given (both
//! ways, sampled every 0.01 mm), keeps corners, is tangent-continuous where the input is
//! smooth at the tolerance, and gives a sampled circle back as one circle whenever the
//! samples allow one within the tolerance.
//!
//! A circle of radius R sampled at n points is a polygon whose chords sag s = R(1 − cos π/n)
//! inside it. No curve through the samples themselves stays within the tolerance of the
//! chords when s exceeds it; the circle midway (radius R − s/2) stays within s/2 of every
//! point of the polygon, and no circle does better. So when s/2 is within the tolerance the
//! fit is a circle of radius from R − s/2 to R (the fitter takes the circle through the
//! samples when they sag less than half the tolerance, else the midway one), and when it is
//! not, the fit keeps to the polygon and only the tolerance is asserted.

use offset_core::biarc::{fit_points, fit_polyline, fit_toolpath, BiarcOptions};
use offset_core::check::sampled_deviation;
use offset_core::geom::{Point, Polyline, Segment};
use offset_core::offset::{offset_polyline, OffsetOptions};
use offset_core::toolpath::{Move, Toolpath, P3};
use proptest::prelude::*;
use std::f64::consts::{PI, TAU};

fn circle_points(r: f64, n: usize) -> Vec<Point> {
    (0..n)
        .map(|i| {
            let a = TAU * i as f64 / n as f64;
            Point::new(r * a.cos(), r * a.sin())
        })
        .collect()
}

/// The sagitta of the chords of a circle of radius r sampled at n points.
fn sagitta(r: f64, n: usize) -> f64 {
    r * (1.0 - (PI / n as f64).cos())
}

/// Asserts every segment is an arc about the origin of radius `radius` within `slack`.
fn arcs_of(pl: &Polyline, radius: f64, slack: f64, what: &str) {
    for s in pl.segments() {
        match s {
            Segment::Arc {
                center, radius: r, ..
            } => {
                assert!(
                    (r - radius).abs() <= slack,
                    "{what}: radius {r}, want {radius} within {slack}"
                );
                assert!(center.len() <= slack, "{what}: centre {center:?}");
            }
            Segment::Line { .. } => panic!("{what}: a line in a fitted circle: {s:?}"),
        }
    }
}

#[test]
fn a_sampled_circle_fits_back_to_one_circle_when_the_sampling_allows() {
    for n in [100, 1000, 10000] {
        for tol in [0.1, 0.01, 0.001] {
            let what = format!("{n} points, tolerance {tol}");
            let pts = circle_points(300.0, n);
            let input = Polyline::from_points(&pts, true);
            let opts = BiarcOptions::with_tolerance(tol);
            let fitted = fit_points(&pts, true, &opts);
            let (dev, at) = sampled_deviation(
                std::slice::from_ref(&input),
                std::slice::from_ref(&fitted),
                0.01,
            );
            assert!(dev <= tol, "{what}: the fit strays {dev} mm at {at:?}");
            let s = sagitta(300.0, n);
            eprintln!(
                "circle r=300, {what}: sagitta {s:.2e}, {} segments, deviation {dev:.2e}",
                fitted.segment_count()
            );
            if s / 2.0 <= tol * 0.99 {
                // the circle through the samples (when they sag less than half the
                // tolerance) or the midway circle: a radius from 300 - s/2 to 300
                let slack = s / 4.0 + 1e-6;
                arcs_of(&fitted, 300.0 - s / 4.0, slack, &what);
                assert!(fitted.segment_count() <= 4, "{what}");
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
                arcs_of(&grown[0], 350.0 - s / 4.0, slack, &what);
            } else {
                // no circle is within the tolerance of this polygon: the fit keeps to it
                assert!(fitted.segment_count() <= n, "{what}");
            }
            let (_, rep) = fit_polyline(&input, &opts);
            assert_eq!(rep.segments_in, n);
            assert_eq!(rep.segments_out, fitted.segment_count());
        }
    }
}

/// The largest sagitta of the input: each chord against the circle through it and the
/// next point (how far the polyline is from any smooth curve through its points).
fn max_sagitta(pts: &[Point]) -> f64 {
    pts.windows(3)
        .map(|w| {
            let (a, b, c) = (w[0], w[1], w[2]);
            let area2 = (b - a).cross(c - a).abs();
            if area2 == 0.0 {
                return 0.0;
            }
            let r = a.dist(b) * b.dist(c) * c.dist(a) / (2.0 * area2);
            let l = a.dist(b).max(b.dist(c));
            l * l / (8.0 * r)
        })
        .fold(0.0, f64::max)
}

fn check_fit(pts: &[Point], closed: bool, tol: f64) -> Result<(), TestCaseError> {
    let fitted = fit_points(pts, closed, &BiarcOptions::with_tolerance(tol));
    let input = Polyline::from_points(pts, closed);
    let (dev, at) = sampled_deviation(
        std::slice::from_ref(&input),
        std::slice::from_ref(&fitted),
        0.01,
    );
    prop_assert!(
        dev <= tol * (1.0 + 1e-9),
        "the fit strays {dev} mm from the input at {at:?} (tolerance {tol})"
    );
    prop_assert!(fitted.segment_count() <= input.segment_count());
    // smooth at the tolerance: consecutive fitted segments meet tangentially
    if max_sagitta(pts) < tol / 4.0 {
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
            // biarcs meet tangentially; a line where no biarc fitted turns by at most
            // 0.01 rad (0.6°) against them
            prop_assert!(ang < 1.0e-2 + 1e-9, "joint {i} turns {ang} rad");
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(offset_core::check::proptest_cases(16)))]
    #[test]
    fn fitted_curves_stay_within_the_tolerance_and_are_smooth(
        amp in 1.0f64..10.0,
        wave in 60.0f64..200.0,
        phase in 0.0f64..TAU,
        n in 200usize..3000,
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
        n in 200usize..3000,
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

    /// Blobs with random wobbles, some sampled coarsely (sagitta above the tolerance) and
    /// some with a few sharp notches cut in (corners).
    #[test]
    fn fitted_blobs_with_notches_stay_within_the_tolerance(
        r0 in 10.0f64..80.0,
        wob in proptest::collection::vec((0.0f64..3.0, 0.0f64..TAU), 1..5),
        n in 30usize..2000,
        notches in proptest::collection::vec(0.0f64..1.0, 0..4),
        tol_exp in -3.0f64..-1.0,
    ) {
        let tol = 10f64.powf(tol_exp);
        let mut pts: Vec<Point> = (0..n)
            .map(|i| {
                let t = TAU * i as f64 / n as f64;
                let r = r0 + wob.iter().enumerate().map(|(k, (a, ph))| a * ((k + 2) as f64 * t + ph).sin()).sum::<f64>();
                Point::new(r * t.cos(), r * t.sin())
            })
            .collect();
        for f in notches {
            let i = ((f * n as f64) as usize).min(n - 1);
            pts[i] = pts[i] * 0.8;
        }
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

#[test]
fn a_coarse_polygon_with_gentle_turns_is_not_rounded_off() {
    // 18 sides of 10 mm: every turn is 20°, below the corner angle, yet the sides sag far
    // more than the tolerance from any circle through the corners
    let n = 18;
    let r = 10.0 / (2.0 * (PI / n as f64).sin());
    let pts = circle_points(r, n);
    let f = fit_points(&pts, true, &BiarcOptions::with_tolerance(0.01));
    let (dev, _) = sampled_deviation(
        &[Polyline::from_points(&pts, true)],
        std::slice::from_ref(&f),
        0.01,
    );
    assert!(dev <= 0.01, "{dev}");
    assert_eq!(f.segment_count(), n, "the polygon comes back as it was");
}

#[test]
fn a_rounded_rectangle_keeps_its_sides_straight_and_its_corners_round() {
    // 100 × 60 with corners of radius 5 sampled at 1° steps
    let mut pts = Vec::new();
    let corners = [(95.0, 55.0), (5.0, 55.0), (5.0, 5.0), (95.0, 5.0)];
    for (k, (cx, cy)) in corners.iter().enumerate() {
        for d in 0..=90 {
            let a = (k as f64 * 90.0 + d as f64).to_radians();
            pts.push(Point::new(cx + 5.0 * a.cos(), cy + 5.0 * a.sin()));
        }
    }
    let tol = 0.001;
    let f = fit_points(&pts, true, &BiarcOptions::with_tolerance(tol));
    let (dev, _) = sampled_deviation(
        &[Polyline::from_points(&pts, true)],
        std::slice::from_ref(&f),
        0.01,
    );
    assert!(dev <= tol, "{dev}");
    let lines = f
        .segments()
        .filter(|s| matches!(s, Segment::Line { .. }) && s.length() > 40.0)
        .count();
    assert_eq!(lines, 4, "four long straight sides: {f:?}");
    assert!(f.segment_count() <= 16, "{} segments", f.segment_count());
}

#[test]
fn a_tool_path_run_of_short_lines_becomes_arcs_and_nothing_else_changes() {
    let mut tp = Toolpath::new("test");
    tp.push(Move::Rapid {
        to: P3::new(20.0, 0.0, 5.0),
    });
    tp.push(Move::Linear {
        to: P3::new(20.0, 0.0, -1.0),
        feed: 300.0,
    });
    for p in circle_points(20.0, 720).iter().skip(1) {
        tp.push(Move::Linear {
            to: P3::at_z(*p, -1.0),
            feed: 800.0,
        });
    }
    tp.push(Move::Linear {
        to: P3::new(20.0, 0.0, -1.0),
        feed: 800.0,
    });
    tp.push(Move::Rapid {
        to: P3::new(20.0, 0.0, 5.0),
    });
    let (fitted, rep) = fit_toolpath(&tp, &BiarcOptions::with_tolerance(0.001));
    assert_eq!(rep.segments_in, tp.moves.len());
    assert!(rep.segments_out <= 2 + 4 + 1, "{rep:?}");
    assert_eq!(fitted.moves[0], tp.moves[0]);
    assert_eq!(fitted.moves[1], tp.moves[1]);
    assert_eq!(fitted.moves.last(), tp.moves.last());
    let (cut0, _) = tp.lengths();
    let (cut1, _) = fitted.lengths();
    assert!((cut0 - cut1).abs() < 0.01, "{cut0} vs {cut1}");
    let arcs = fitted
        .moves
        .iter()
        .filter(|m| matches!(m, Move::Arc { .. }))
        .count();
    assert!(arcs >= 2, "{:?}", fitted.moves);
}
