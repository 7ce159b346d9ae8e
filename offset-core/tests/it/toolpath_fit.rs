//! Arcs everywhere: a circle given as points comes out of import, profile and the final
//! fitting pass as a few arcs of the offset radius; and the fitting pass over any tool
//! path stays within the tolerance of the moves it replaces (sampled every 0.01 mm).
//!
//! A circle of radius 300 sampled at n points is a polygon whose sides sag
//! s = 300 (1 − cos π/n) inside it: 0.148 mm at 100 points, 0.0015 mm at 1 000, 1.5e-5 mm at
//! 10 000. Import fits the polygon, not the circle it may stand for, within the tolerance:
//! when s/2 is within the tolerance that is one circle, of radius 300 (the samples' circle,
//! when they sag less than half the tolerance) down to 300 − s/2 (the circle midway between
//! the samples and the sides); otherwise no circle is within the tolerance of the polygon
//! and the polygon stays. So the 100-point circle comes back whole only at 0.1 mm, as a
//! circle of radius 299.93 whose offset is 349.93 — as near 350 as the polygon allows, and
//! no nearer; at 0.01 and 0.001 mm its profile keeps the polygon's sides, whose offset lies
//! between 350 − s and 350.

use crate::pocket_support;

use offset_core::biarc::{fit_toolpath, BiarcOptions};
use offset_core::check::sampled_deviation;
use offset_core::geom::{Point, Polyline, Shape, Vertex};
use offset_core::io::{read_shape_with, ReadOptions};
use offset_core::ops::{pocket, profile, Cutting, PocketParams, ProfileParams, Side, Stepover};
use offset_core::toolpath::{arc_segment, Move, Tool, Toolpath, P3};
use proptest::prelude::*;
use std::collections::BTreeMap;
use std::f64::consts::{PI, TAU};

fn circle_points(r: f64, n: usize) -> Vec<Point> {
    (0..n)
        .map(|i| {
            let a = TAU * i as f64 / n as f64;
            Point::new(r * a.cos(), r * a.sin())
        })
        .collect()
}

fn circle_json(n: usize) -> Vec<u8> {
    let vs: Vec<String> = circle_points(300.0, n)
        .iter()
        .map(|p| format!("[{:?},{:?}]", p.x, p.y))
        .collect();
    format!(
        r#"{{"units":"mm","paths":[{{"closed":true,"vertices":[{}]}}]}}"#,
        vs.join(",")
    )
    .into_bytes()
}

fn circle_dxf(n: usize) -> Vec<u8> {
    let mut e = format!("0\nSECTION\n2\nENTITIES\n0\nLWPOLYLINE\n90\n{n}\n70\n1\n");
    for p in circle_points(300.0, n) {
        e.push_str(&format!("10\n{:?}\n20\n{:?}\n", p.x, p.y));
    }
    e.push_str("0\nENDSEC\n0\nEOF\n");
    e.into_bytes()
}

/// The cutting moves below the stock top, with where each starts.
fn cuts_below_top(tp: &Toolpath) -> Vec<(P3, Move, P3)> {
    let mut out = Vec::new();
    tp.walk(P3::default(), |from, m, to| {
        if matches!(m, Move::Linear { .. } | Move::Arc { .. }) && to.z < -1e-12 {
            out.push((from, m.clone(), to));
        }
    });
    out
}

#[test]
fn circles_of_radius_300_profile_outside_as_a_few_arcs_of_radius_350() {
    for (what, make, file) in [
        ("JSON", circle_json as fn(usize) -> Vec<u8>, "c.json"),
        ("DXF LWPOLYLINE", circle_dxf, "c.dxf"),
    ] {
        for n in [100, 1000, 10000] {
            for tol in [0.1, 0.01, 0.001] {
                let case = format!("{what}, {n} points, tolerance {tol}");
                let (shape, _) = read_shape_with(
                    &make(n),
                    file,
                    &ReadOptions {
                        tolerance: tol,
                        ..Default::default()
                    },
                )
                .unwrap();
                let p = ProfileParams {
                    side: Side::Outside,
                    cut: Cutting {
                        tool: Tool::flat(100.0),
                        depth: 1.0,
                        stepdown: 1.0,
                        tolerance: tol,
                        ..Default::default()
                    },
                    ..Default::default()
                };
                let planned = profile(&shape, &p).unwrap();
                let (tp, _) = fit_toolpath(&planned, &BiarcOptions::with_tolerance(tol));
                let cuts = cuts_below_top(&tp);
                let s = 300.0 * (1.0 - (PI / n as f64).cos());
                eprintln!(
                    "{case}: sagitta {s:.2e}, {} cutting moves ({} before the fitting pass)",
                    cuts.len(),
                    cuts_below_top(&planned).len()
                );
                if s / 2.0 <= 0.99 * tol {
                    // one circle: the ramp down along it and the lap, all arcs of radius
                    // 350 (less s/2 where the polygon sags more than 1e-3 from it)
                    assert!(cuts.len() <= 8, "{case}: {} cutting moves", cuts.len());
                    let slack = if s / 2.0 < 1e-3 { 1e-3 } else { s / 2.0 + 1e-6 };
                    for (from, m, _) in &cuts {
                        let Move::Arc { center, .. } = m else {
                            panic!("{case}: a cutting move that is no arc: {m:?}");
                        };
                        let r = from.xy().dist(*center);
                        assert!((r - 350.0).abs() <= slack, "{case}: an arc of radius {r}");
                        assert!(center.len() <= slack, "{case}: centre {center:?}");
                    }
                } else {
                    // no circle within the tolerance of this polygon: the profile keeps to
                    // the polygon's offset, between 350 - s and 350
                    assert!(cuts.len() <= 2 * n + 8, "{case}: {} moves", cuts.len());
                    let mut one = Toolpath::new("");
                    for (from, m, to) in &cuts {
                        one.moves = vec![m.clone()];
                        for q in one.sample(*from, 1.0) {
                            let r = q.xy().len();
                            assert!(
                                r >= 350.0 - s - tol - 1e-9 && r <= 350.0 + tol,
                                "{case}: a cut at radius {r} ({from:?} -> {to:?})"
                            );
                        }
                    }
                }
            }
        }
    }
}

/// The horizontal cutting moves of a tool path by height: each as a polyline of one
/// segment (lines and arcs), to compare a fitted path with the path it came from.
fn level_paths(tp: &Toolpath) -> BTreeMap<i64, Vec<Polyline>> {
    let mut out: BTreeMap<i64, Vec<Polyline>> = BTreeMap::new();
    tp.walk(P3::default(), |from, m, to| {
        if from.z != to.z || from.xy() == to.xy() {
            return;
        }
        let bulge = match m {
            Move::Linear { .. } => 0.0,
            Move::Arc { center, ccw, .. } => {
                (arc_segment(from.xy(), to.xy(), *center, *ccw).sweep() / 4.0).tan()
            }
            _ => return,
        };
        out.entry((to.z * 1e9).round() as i64)
            .or_default()
            .push(Polyline::new(
                vec![Vertex::new(from.x, from.y, bulge), Vertex::line(to.xy())],
                false,
            ));
    });
    out
}

/// Every move the fitting pass must leave alone: all but horizontal straight cuts.
fn kept(tp: &Toolpath) -> Vec<Move> {
    let mut out = Vec::new();
    tp.walk(P3::default(), |from, m, to| {
        let level_cut = matches!(m, Move::Linear { .. } | Move::Arc { .. }) && from.z == to.z;
        if !level_cut {
            out.push(m.clone());
        }
    });
    out
}

/// The first arc the fitting pass made (one not among the input's moves) whose ends lie on
/// circles about its centre differing by more than 1e-9 of the radius: (from, to, centre).
fn arc_off_its_circle(input: &Toolpath, fitted: &Toolpath) -> Option<(P3, P3, Point)> {
    let mut bad = None;
    fitted.walk(P3::default(), |from, m, to| {
        if let Move::Arc { center, .. } = m {
            let (r0, r1) = (from.xy().dist(*center), to.xy().dist(*center));
            if (r0 - r1).abs() > 1e-9 * r0.max(r1) && !input.moves.contains(m) && bad.is_none() {
                bad = Some((from, to, *center));
            }
        }
    });
    bad
}

fn check_fitted(tp: &Toolpath, tol: f64) -> Result<(), TestCaseError> {
    let (fitted, rep) = fit_toolpath(tp, &BiarcOptions::with_tolerance(tol));
    prop_assert!(rep.segments_out <= rep.segments_in);
    prop_assert_eq!(pocket_support::disjoint_arc(tp), None);
    prop_assert_eq!(pocket_support::disjoint_arc(&fitted), None);
    prop_assert_eq!(arc_off_its_circle(tp, &fitted), None);
    prop_assert_eq!(
        kept(&fitted),
        kept(tp),
        "moves other than level cuts changed"
    );
    let (before, after) = (level_paths(tp), level_paths(&fitted));
    prop_assert_eq!(
        before.keys().collect::<Vec<_>>(),
        after.keys().collect::<Vec<_>>()
    );
    for (z, paths) in &before {
        let (dev, at) = sampled_deviation(paths, &after[z], 0.01);
        prop_assert!(
            dev <= tol * (1.0 + 1e-9),
            "at Z{}: the fitted path strays {} mm at {:?} (tolerance {})",
            *z as f64 * 1e-9,
            dev,
            at,
            tol
        );
    }
    Ok(())
}

/// A pocket and an outside profile of `shape` at tolerance `tol`, each fitted and checked.
fn check_pocket_and_profile(shape: &Shape, tol: f64) -> Result<(), TestCaseError> {
    let cut = Cutting {
        tool: Tool::flat(3.0),
        depth: 1.0,
        stepdown: 0.5,
        tolerance: tol,
        ..Default::default()
    };
    let pk = PocketParams {
        cut: cut.clone(),
        stepover: Stepover::Percent(45.0),
    };
    check_fitted(&pocket(shape, &pk).unwrap(), tol)?;
    let pr = ProfileParams {
        side: Side::Outside,
        cut,
        lead_in: 2.0,
        ..Default::default()
    };
    check_fitted(&profile(shape, &pr).unwrap(), tol)
}

/// A blob r = r0 + Σ a sin(kθ + φ) sampled at n points, with sharp notches pressed in.
fn blob(r0: f64, wob: &[(f64, f64)], n: usize, notches: &[f64]) -> Polyline {
    let mut pts: Vec<Point> = (0..n)
        .map(|i| {
            let t = TAU * i as f64 / n as f64;
            let r = r0
                + wob
                    .iter()
                    .enumerate()
                    .map(|(k, (a, ph))| a * ((k + 2) as f64 * t + ph).sin())
                    .sum::<f64>();
            Point::new(r * t.cos(), r * t.sin())
        })
        .collect();
    for f in notches {
        let i = ((f * n as f64) as usize).min(n - 1);
        pts[i] = pts[i] * 0.85;
    }
    Polyline::from_points(&pts, true)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(offset_core::check::proptest_cases(10)))]

    /// Pockets and profiles of random blobs given as points (not fitted on import, so the
    /// passes are runs of short lines), fitted afterwards: within the tolerance everywhere.
    #[test]
    fn fitted_tool_paths_stay_within_the_tolerance_of_the_unfitted_ones(
        r0 in 6.0f64..14.0,
        wob in proptest::collection::vec((0.0f64..1.5, 0.0f64..TAU), 1..4),
        n in 40usize..600,
        notches in proptest::collection::vec(0.0f64..1.0, 0..3),
        tol_exp in -3.0f64..-1.5,
    ) {
        let tol = 10f64.powf(tol_exp);
        let shape = Shape::new(vec![blob(r0, &wob, n, &notches)]);
        prop_assume!(offset_core::check::first_crossing(&shape.paths, tol).is_none());
        check_pocket_and_profile(&shape, tol)?;
    }
}

#[test]
fn the_fitting_pass_shortens_pocket_programs_of_dense_outlines() {
    let shape = Shape::new(vec![blob(20.0, &[(1.0, 0.3)], 2000, &[])]);
    let p = PocketParams {
        stepover: Stepover::Percent(40.0),
        cut: Cutting {
            tool: Tool::flat(3.0),
            ..Default::default()
        },
    };
    let tp = pocket(&shape, &p).unwrap();
    let (fitted, rep) = fit_toolpath(&tp, &BiarcOptions::with_tolerance(1e-3));
    eprintln!("pocket of a 2000-point blob: {rep:?}");
    assert!(rep.segments_out * 5 < rep.segments_in, "{rep:?}");
    let _ = pocket_support::descents(&fitted);
}

#[test]
fn the_fitting_pass_turns_the_profile_of_a_circle_given_as_points_into_arcs() {
    // issue 13's first example, without the import's fitting: 7 200 points, a 100 mm tool,
    // 0.01 mm. The offset is 7 200 sides with as many short round joins between them (no
    // two lines in a row), all within the sides' sagitta (3e-5 mm) of the circle of 350.
    let shape = Shape::new(vec![Polyline::from_points(
        &circle_points(300.0, 7200),
        true,
    )]);
    let tol = 0.01;
    let p = ProfileParams {
        side: Side::Outside,
        cut: Cutting {
            tool: Tool::flat(100.0),
            tolerance: tol,
            ..Default::default()
        },
        ..Default::default()
    };
    let planned = profile(&shape, &p).unwrap();
    assert!(cuts_below_top(&planned).len() > 14_000);
    let (tp, _) = fit_toolpath(&planned, &BiarcOptions::with_tolerance(tol));
    // the lap at depth: a few arcs. (The ramp down to it follows the loop as it was
    // planned, side by side, and is kept: the pass leaves descending moves alone, and read
    // as `plan` reads it the circle is arcs before it is offset.)
    let cuts: Vec<_> = cuts_below_top(&tp)
        .into_iter()
        .filter(|(from, _, to)| from.z == to.z)
        .collect();
    assert!(cuts.len() <= 8, "{} cutting moves at depth", cuts.len());
    let mut one = Toolpath::new("");
    for (from, m, _) in &cuts {
        assert!(matches!(m, Move::Arc { .. }), "{m:?}");
        one.moves = vec![m.clone()];
        for q in one.sample(*from, 1.0) {
            let r = q.xy().len();
            assert!((r - 350.0).abs() <= tol, "a cut at radius {r}");
        }
    }
}

/// The draw a fresh seed found (docs/testing.md): the fitting pass emitted an arc whose ends
/// lay on circles about its centre differing by more than 1e-6 of the radius.
#[test]
fn the_fitted_blob_of_radius_12_7_keeps_each_arc_on_one_circle() {
    let tol = 10f64.powf(-1.8542966460846235);
    let shape = Shape::new(vec![blob(
        12.719994657464817,
        &[(0.013099907771876763, 0.38115626201492403)],
        190,
        &[0.37795308427431223],
    )]);
    assert!(offset_core::check::first_crossing(&shape.paths, tol).is_none());
    check_pocket_and_profile(&shape, tol).unwrap();
}
