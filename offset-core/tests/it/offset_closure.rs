//! Closure: every offset the kernel hands back is valid kernel input again (no crossings,
//! no back-steps or slivers where the prune cut and stitched), so an offset can be offset
//! again, as a pocket does pass after pass. Random dense gears and stars are offset
//! inwards and outwards many times over, every result checked by the kernel's own input
//! rule and by the distance checker; and the gear of issue 13, whose inward offset by 2 mm
//! once carried a 1.8e-9 mm back-step at a seam the kernel then refused.

use crate::common::*;
use offset_core::check::first_crossing;
use offset_core::geom::{Point, Polyline, Region};
use offset_core::offset::{offset_region, OffsetOptions};
use proptest::prelude::*;
use std::f64::consts::TAU;

/// Offsets `start` by `d` again and again (every piece of every result), checking each
/// result is valid input (and every eighth at the distance asked from the one before);
/// returns how many offsets were made.
fn offset_again(start: Region, d: f64, times: usize, tol: f64) -> Result<usize, String> {
    let opts = OffsetOptions {
        tolerance: tol,
        ..Default::default()
    };
    let mut cur = vec![start];
    let mut made = 0;
    for step in 0..times {
        let mut next = Vec::new();
        for r in &cur {
            let out = offset_region(r, d, &opts)
                .map_err(|e| format!("offset {step} of a result refused: {e}"))?;
            let paths = region_paths(&out);
            if let Some((path, at)) = first_crossing(&paths, tol) {
                return Err(format!(
                    "offset {step}: result path {path} crosses itself at {at:?}"
                ));
            }
            // the distance, every eighth offset (the checker costs far more than the offset)
            if step % 8 == 0 {
                let input: Vec<Polyline> = r.boundaries().cloned().collect();
                let rep = offset_core::check::check_offset(&input, &paths, d, tol);
                if !rep.within(tol) {
                    return Err(format!("offset {step} deviates: {rep:?}"));
                }
            }
            made += 1;
            next.extend(out);
        }
        if next.is_empty() {
            break;
        }
        cur = next;
    }
    Ok(made)
}

#[test]
fn the_issue_13_gear_offset_inwards_by_2_mm_is_valid_input_again() {
    // r = 60 + 4 sin 24θ + 3 sin 5θ at 100 000 vertices
    let g = gear(100_000, 60.0, &[(4.0, 24.0, 0.0), (3.0, 5.0, 0.0)]);
    let n = offset_again(Region::new(g, vec![]), -2.0, 3, 1e-3).unwrap();
    assert!(n >= 3);
}

#[test]
fn dense_gears_offset_again_at_pocket_steps_until_nothing_is_left() {
    let g = gear(4_000, 60.0, &[(4.0, 24.0, 0.0), (3.0, 5.0, 0.0)]);
    let islands = vec![
        Polyline::circle(Point::new(25.0, 0.0), 6.0).reversed(),
        Polyline::circle(Point::new(-20.0, 15.0), 5.0).reversed(),
    ];
    offset_again(Region::new(g, islands), -1.5, 60, 1e-3).unwrap();
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(offset_core::check::proptest_cases(12)))]

    /// Dense wavy outlines, offset inwards or outwards six times.
    #[test]
    fn offsets_of_offsets_of_dense_gears_stay_valid(
        n in 500usize..3000,
        r0 in 20.0f64..60.0,
        waves in proptest::collection::vec((0.2f64..4.0, 2.0f64..40.0, 0.0f64..TAU), 1..4),
        d in prop_oneof![-3.0f64..-0.3, 0.3f64..3.0],
        tol_exp in -3.0f64..-2.0,
    ) {
        let tol = 10f64.powf(tol_exp);
        let amp: f64 = waves.iter().map(|w| w.0).sum();
        prop_assume!(amp < r0 * 0.5);
        let g = gear(n, r0, &waves.iter().map(|&(a, f, p)| (a, f.round(), p)).collect::<Vec<_>>());
        offset_again(Region::new(g, vec![]), d, 6, tol).map_err(TestCaseError::fail)?;
    }

    /// Random stars with some bulged sides, offset eight times.
    #[test]
    fn offsets_of_offsets_of_stars_with_arcs_stay_valid(
        radii in proptest::collection::vec(10.0f64..40.0, 5..40),
        bulges in proptest::collection::vec(-0.3f64..0.3, 5..40),
        d in prop_oneof![-2.0f64..-0.2, 0.2f64..2.0],
    ) {
        let s = star_with_arcs(Point::new(0.0, 0.0), &radii, &bulges);
        // some random bulges make the star cross itself: only valid input is offset
        prop_assume!(first_crossing(std::slice::from_ref(&s), 1e-3).is_none());
        offset_again(Region::new(s, vec![]), d, 8, 1e-3).map_err(TestCaseError::fail)?;
    }
}
