//! Regions with islands: islands grow while the outer shrinks, merge, split the pocket,
//! vanish, and swallow the outer (Park 2001); checked by distance and by Clipper2's area.

use crate::common::*;
use offset_core::check::first_crossing;
use offset_core::geom::{Point, Polyline, Region};
use offset_core::offset::{offset_region, OffsetError, OffsetOptions};
use proptest::prelude::*;
use std::f64::consts::PI;

fn opts() -> OffsetOptions {
    OffsetOptions::default()
}

fn check(region: &Region, d: f64) -> Vec<Region> {
    let out = offset_region(region, d, &opts()).unwrap();
    let input: Vec<Polyline> = region.boundaries().cloned().collect();
    let paths = region_paths(&out);
    assert_offset(&input, &paths, d, 1e-3);
    assert_area(&input, &paths, d, 1e-3);
    for r in &out {
        assert!(r.outer.is_ccw(), "outer must run counter-clockwise");
        for i in &r.islands {
            assert!(!i.is_ccw(), "islands must run clockwise");
            assert!(r.outer.contains(i.vertices[0].pos()));
        }
    }
    out
}

#[test]
fn island_grows_while_outer_shrinks_then_merges() {
    let outer = Polyline::rect(Point::new(0.0, 0.0), Point::new(100.0, 60.0));
    let island = Polyline::circle(Point::new(50.0, 30.0), 10.0);
    let region = Region::new(outer, vec![island]);
    let out = check(&region, -5.0);
    assert_eq!(out.len(), 1);
    assert_eq!(out[0].islands.len(), 1);
    // the island's offset is a circle of radius 15
    assert!((out[0].islands[0].area() + 225.0 * PI).abs() < 1e-6);
    // at 12 the island (radius 22) reaches the shrunk outer's sides (y = 12 and 48): the
    // pocket splits into a left and a right part
    let out = check(&region, -12.0);
    assert_eq!(out.len(), 2, "{out:?}");
    assert!(out.iter().all(|r| r.islands.is_empty()));
    // far enough, nothing is left
    assert!(check(&region, -31.0).is_empty());
}

#[test]
fn islands_merge_with_each_other() {
    let outer = Polyline::rect(Point::new(0.0, 0.0), Point::new(100.0, 100.0));
    let a = Polyline::circle(Point::new(40.0, 50.0), 5.0);
    let b = Polyline::circle(Point::new(60.0, 50.0), 5.0);
    let region = Region::new(outer, vec![a, b]);
    let out = check(&region, -3.0);
    assert_eq!(out[0].islands.len(), 2);
    let out = check(&region, -6.0);
    assert_eq!(out.len(), 1);
    assert_eq!(out[0].islands.len(), 1, "the two islands merge into one");
}

#[test]
fn islands_vanish_when_the_region_grows() {
    let outer = Polyline::rect(Point::new(0.0, 0.0), Point::new(50.0, 50.0));
    let a = Polyline::circle(Point::new(25.0, 25.0), 4.0);
    let region = Region::new(outer, vec![a]);
    let out = check(&region, 3.0);
    assert_eq!(out[0].islands.len(), 1);
    let out = check(&region, 4.5);
    assert_eq!(out.len(), 1);
    assert!(out[0].islands.is_empty());
}

#[test]
fn an_island_swallowing_the_outer_removes_both() {
    // a ring: the island's offset inverts the containment with the outer's
    let outer = Polyline::circle(Point::new(0.0, 0.0), 10.0);
    let island = Polyline::circle(Point::new(0.0, 0.0), 6.0);
    let region = Region::new(outer, vec![island]);
    let out = check(&region, -1.5);
    assert_eq!(out.len(), 1);
    assert!((out[0].area() - PI * (8.5 * 8.5 - 7.5 * 7.5)).abs() < 1e-6);
    assert!(check(&region, -2.5).is_empty());
}

fn region_strategy() -> impl Strategy<Value = (Vec<f64>, Vec<(f64, f64, bool)>, f64)> {
    (
        prop::collection::vec(25.0f64..40.0, 6..30),
        prop::collection::vec((1.0f64..6.0, 0.0f64..1.0, any::<bool>()), 0..6),
        -12.0f64..6.0,
    )
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(offset_core::check::proptest_cases(600)))]

    #[test]
    fn random_regions_keep_their_distance((radii, islands, d) in region_strategy()) {
        prop_assume!(d.abs() > 1e-3);
        let outer = star(Point::new(0.0, 0.0), &radii);
        // islands on a ring of radius 12, spaced so they never touch each other
        let k = islands.len().max(1);
        let isl: Vec<Polyline> = islands
            .iter()
            .enumerate()
            .map(|(i, &(r, jitter, round))| {
                let a = (i as f64 + 0.3 * jitter) / k as f64 * std::f64::consts::TAU;
                let c = Point::new(a.cos(), a.sin()) * 12.0;
                let r = r.min(12.0 * (PI / k as f64).sin() - 0.5).max(0.5);
                if round {
                    Polyline::circle(c, r)
                } else {
                    star(c, &[r, r * 0.6, r, r * 0.7, r * 0.9])
                }
            })
            .collect();
        let region = Region::new(outer, isl);
        let all: Vec<Polyline> = region.boundaries().cloned().collect();
        prop_assume!(offset_core::check::first_crossing(&all, 1e-3).is_none());
        check(&region, d);
    }
}

#[test]
fn island_touching_the_outer_at_one_point_offsets_both_ways() {
    // an island touching the outer wall (not crossing it) is a valid region: it used to be
    // rejected as crossing itself. Touching at a vertex of the island (x = 0) and inside one
    // of its arcs (y = 0).
    let outer = Polyline::rect(Point::new(0.0, 0.0), Point::new(100.0, 100.0));
    for centre in [Point::new(10.0, 50.0), Point::new(50.0, 10.0)] {
        let island = Polyline::circle(centre, 10.0);
        let region = Region::new(outer.clone(), vec![island.clone()]);
        assert_eq!(first_crossing(&[outer.clone(), island.clone()], 1e-3), None);
        // inward the island (radius 11) grows through the shrunk wall (1 from it): the
        // pocket is the 98 × 98 square less the part of the disc inside it, no island
        let out = check(&region, -1.0);
        assert_eq!(out.len(), 1, "{out:?}");
        assert!(out[0].islands.is_empty());
        let cap = 121.0 * (9.0f64 / 11.0).acos() - 9.0 * 40f64.sqrt();
        let want = 98.0 * 98.0 - (121.0 * PI - cap);
        assert!((out[0].outer.area() - want).abs() < 1e-6, "{out:?}");
        // outward the island (radius 9) comes off the wall
        let out = check(&region, 1.0);
        assert_eq!(out.len(), 1);
        assert_eq!(out[0].islands.len(), 1);
        assert!((out[0].islands[0].area() + 81.0 * PI).abs() < 1e-6);
    }
    // an island reaching 1e-3 past the wall still crosses it
    let island = Polyline::circle(Point::new(9.999, 50.0), 10.0);
    let err = offset_region(&Region::new(outer, vec![island]), -1.0, &opts()).unwrap_err();
    assert!(matches!(err, OffsetError::SelfIntersecting { .. }), "{err}");
}

#[test]
fn a_pass_whose_island_just_meets_the_wall_can_be_offset_again() {
    // island 20 from the wall, pass of 10: the island (radius 20) exactly meets the shrunk
    // wall at x = 10, and that region is the next pass's input
    let outer = Polyline::rect(Point::new(0.0, 0.0), Point::new(100.0, 100.0));
    let region = Region::new(outer, vec![Polyline::circle(Point::new(30.0, 50.0), 10.0)]);
    let first = check(&region, -10.0);
    assert_eq!(first.len(), 1);
    assert_eq!(first[0].islands.len(), 1, "touching, still an island");
    // the next pass: the 78 × 78 square less the disc of radius 21 (centre 19 from x = 11)
    let out = check(&first[0], -1.0);
    assert_eq!(out.len(), 1);
    assert!(out[0].islands.is_empty());
    let cap = 441.0 * (19.0f64 / 21.0).acos() - 19.0 * 80f64.sqrt();
    let want = 78.0 * 78.0 - (441.0 * PI - cap);
    assert!((out[0].outer.area() - want).abs() < 1e-6, "{out:?}");
}
