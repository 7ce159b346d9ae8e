//! One input offset at distances spread over three decades (from d0 to 1000 d0, inward
//! and outward): every result is valid input again (no crossings), keeps its distance
//! from the input (the checker), and the results nest (each deeper shrink lies inside the
//! one before, each larger growth around it, at the difference of the distances). Large
//! distances are made in stages (docs/offset.md, "Large distances"), small ones in one, so
//! this also holds the two ways to the same answer.

use crate::common::*;
use offset_core::check::{check_offset, first_crossing};
use offset_core::geom::{Point, Polyline, Region};
use offset_core::offset::{offset_region, OffsetOptions};
use proptest::prelude::*;
use std::f64::consts::TAU;

/// Offsets `region` at each distance (all one sign, growing in size) and checks each
/// result and each pair of neighbours; returns the number of non-empty results.
fn offsets_nest(region: &Region, ds: &[f64], tol: f64) -> Result<usize, String> {
    let opts = OffsetOptions {
        tolerance: tol,
        ..Default::default()
    };
    let input: Vec<Polyline> = region.boundaries().cloned().collect();
    let mut prev: Option<(f64, Vec<Region>)> = None;
    let mut made = 0;
    for &d in ds {
        let out = offset_region(region, d, &opts).map_err(|e| format!("d = {d}: {e}"))?;
        let paths = region_paths(&out);
        if let Some((path, at)) = first_crossing(&paths, tol) {
            return Err(format!(
                "d = {d}: result path {path} crosses itself at {at:?}"
            ));
        }
        let rep = check_offset(&input, &paths, d, tol);
        if !rep.within(tol) {
            return Err(format!("d = {d}: deviates from the input: {rep:?}"));
        }
        if let Some((pd, before)) = &prev {
            let before_paths = region_paths(before);
            // nested at the difference of the distances
            let rep = check_offset(&before_paths, &paths, d - pd, tol);
            if !rep.within(tol) {
                return Err(format!(
                    "d = {d}: not the offset by {} of the result at {pd}: {rep:?}",
                    d - pd
                ));
            }
            // and on the right side of it: a deeper shrink inside, a larger growth around
            for p in &paths {
                for v in &p.vertices {
                    let q = Point::new(v.x, v.y);
                    let in_before = before.iter().any(|r| r.contains(q));
                    if d < 0.0 && !in_before {
                        return Err(format!(
                            "d = {d}: vertex {q:?} lies outside the result at {pd}"
                        ));
                    }
                    if d > 0.0 && in_before {
                        return Err(format!(
                            "d = {d}: vertex {q:?} lies inside the result at {pd}"
                        ));
                    }
                }
            }
        }
        if !out.is_empty() {
            made += 1;
        }
        prev = Some((d, out));
    }
    Ok(made)
}

/// Distances d0 · 1000^(k / (count - 1)), k = 0 … count - 1.
fn three_decades(d0: f64, count: usize) -> Vec<f64> {
    (0..count)
        .map(|k| d0 * 1000f64.powf(k as f64 / (count - 1) as f64))
        .collect()
}

#[test]
fn a_gear_with_islands_shrunk_from_a_hundredth_to_ten_mm_nests() {
    // the bench's 1k gear shape at 600 points: r = 100 + 3 sin 50θ, islands r = 8 on a ring of 60
    let g = gear(600, 100.0, &[(3.0, 50.0, 0.0)]);
    let islands = (0..4)
        .map(|k| {
            let a = TAU * k as f64 / 4.0;
            Polyline::circle(Point::new(a.cos(), a.sin()) * 60.0, 8.0).reversed()
        })
        .collect();
    let ds: Vec<f64> = three_decades(0.04, 6).iter().map(|d| -d).collect();
    let made = offsets_nest(&Region::new(g, islands), &ds, 1e-3).unwrap();
    assert_eq!(made, ds.len(), "every shrink up to 40 mm leaves something");
}

/// The draw of a wavy outline: its vertex count, radius, waves (amplitude, count, phase)
/// and maybe a round island (its angle from the centre and radius).
type Wavy = (usize, f64, Vec<(f64, f64, f64)>, Option<(f64, f64)>);

/// The draws of [`wavy_region`].
fn wavy() -> impl Strategy<Value = Wavy> {
    (
        200usize..800,
        30.0f64..60.0,
        proptest::collection::vec((0.3f64..3.0, 5.0f64..40.0, 0.0f64..TAU), 1..3),
        proptest::option::of((0.0f64..TAU, 2.0f64..5.0)),
    )
}

/// The region of a draw: the wavy outline (its waves a whole number round), the island at
/// 0.4 of the radius; none when the waves add up to 0.3 of the radius or more.
fn wavy_region((n, r0, waves, island): &Wavy) -> Option<Region> {
    let amp: f64 = waves.iter().map(|w| w.0).sum();
    if amp >= r0 * 0.3 {
        return None;
    }
    let g = gear(
        *n,
        *r0,
        &waves
            .iter()
            .map(|&(a, f, p)| (a, f.round(), p))
            .collect::<Vec<_>>(),
    );
    let islands = island
        .map(|(a, r)| Polyline::circle(Point::new(a.cos(), a.sin()) * (r0 * 0.4), r).reversed())
        .into_iter()
        .collect();
    Some(Region::new(g, islands))
}

/// Runs the property `test` (named for its regression records) on `strategy` at the case
/// count every other property runs divided by `share` (4 at least), and fails the test
/// with proptest's report.
fn run_share<S: Strategy>(
    test: &'static str,
    share: u32,
    strategy: S,
    property: impl Fn(S::Value) -> Result<(), TestCaseError>,
) where
    S::Value: std::fmt::Debug,
{
    use proptest::test_runner::{contextualize_config, TestError, TestRunner};
    let mut config = contextualize_config(ProptestConfig {
        cases: offset_core::check::proptest_cases(128),
        source_file: Some(file!()),
        ..ProptestConfig::default()
    });
    config.cases = (config.cases / share).max(4);
    config.test_name = Some(test);
    match TestRunner::new(config).run(&strategy, property) {
        Ok(()) => {}
        Err(TestError::Fail(why, draw)) => panic!("{why}\nminimal failing input: {draw:?}"),
        Err(TestError::Abort(why)) => panic!("aborted: {why}"),
    }
}

/// Dense wavy outlines, with or without an island, shrunk or grown at five distances over
/// three decades.
///
/// One case costs about as much as a hundred cases of the other properties (five offsets
/// and two-way distance checks at 1e-3 on each), so this property runs a 32nd of the case
/// count every other property runs: 8 at CI's `PROPTEST_CASES=256`, 80 at the deep run's
/// 2560, 4 at least. Seed, regression file and failure report are proptest's as for the
/// `proptest!` tests (its runner is built from the same environment).
#[test]
fn offsets_over_three_decades_are_valid_and_nested() {
    run_share(
        "offset_distances::offsets_over_three_decades_are_valid_and_nested",
        32,
        (wavy(), 0.005f64..0.03, any::<bool>()),
        |(draw, d0, grow)| {
            let region = wavy_region(&draw);
            prop_assume!(region.is_some());
            let sign = if grow { 1.0 } else { -1.0 };
            let ds: Vec<f64> = three_decades(d0, 5).iter().map(|d| sign * d).collect();
            offsets_nest(&region.unwrap(), &ds, 1e-3).map_err(TestCaseError::fail)?;
            Ok(())
        },
    );
}

/// Pocket passes each from the one before, made from the kernel's own result
/// (`ValidRegions::offset`, which skips the input check's crossing search), are the passes
/// `offset_regions` makes from the same regions (which checks them): the same regions, to
/// the bit, pass after pass, and each valid input again. Wavy outlines with or without an
/// island, shrunk until nothing is left or grown, at 1e-3 (debug builds also assert, in
/// the kernel, that each skipped check would have passed).
#[test]
fn passes_from_the_kernels_result_are_the_checked_passes() {
    use offset_core::offset::{offset_regions, offset_regions_valid};
    run_share(
        "offset_distances::passes_from_the_kernels_result_are_the_checked_passes",
        16,
        (wavy(), 0.5f64..8.0, any::<bool>()),
        |(draw, step, grow)| {
            let region = wavy_region(&draw);
            prop_assume!(region.is_some());
            let d = if grow { step } else { -step };
            let opts = OffsetOptions::default();
            let given = vec![region.unwrap()];
            let mut made = offset_regions_valid(&given, d, &opts)
                .map_err(|e| TestCaseError::fail(format!("pass 1: {e}")))?;
            let mut checked = offset_regions(&given, d, &opts)
                .map_err(|e| TestCaseError::fail(format!("pass 1, checked: {e}")))?;
            for pass in 1..=12 {
                prop_assert_eq!(made.regions(), checked.as_slice(), "pass {}", pass);
                let paths = region_paths(&checked);
                if let Some((path, at)) = first_crossing(&paths, opts.tolerance) {
                    return Err(TestCaseError::fail(format!(
                        "pass {pass}: path {path} crosses itself at {at:?}"
                    )));
                }
                if checked.is_empty() {
                    break;
                }
                made = made
                    .offset(d, &opts)
                    .map_err(|e| TestCaseError::fail(format!("pass {}: {e}", pass + 1)))?;
                checked = offset_regions(&checked, d, &opts)
                    .map_err(|e| TestCaseError::fail(format!("pass {}, checked: {e}", pass + 1)))?;
            }
            Ok(())
        },
    );
}
