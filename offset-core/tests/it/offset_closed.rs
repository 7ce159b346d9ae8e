//! Closed offsets of single polylines: known answers, the distance property and Clipper2's
//! area on random star polygons with lines and arcs.

use crate::common::*;
use offset_core::geom::{Point, Polyline};
use offset_core::offset::{offset_polyline, OffsetOptions};
use proptest::prelude::*;
use std::f64::consts::PI;

fn opts() -> OffsetOptions {
    OffsetOptions::default()
}

#[test]
fn square_grows_with_round_corners_and_shrinks_square() {
    let sq = Polyline::rect(Point::new(0.0, 0.0), Point::new(10.0, 10.0));
    let out = offset_polyline(&sq, 1.0, &opts()).unwrap();
    assert_eq!(out.len(), 1);
    assert!(
        (out[0].area() - (100.0 + 40.0 + PI)).abs() < 1e-9,
        "{out:?}"
    );
    assert!(out[0].is_ccw());
    assert_eq!(out[0].len(), 8);
    assert_offset(std::slice::from_ref(&sq), &out, 1.0, 1e-3);
    let out = offset_polyline(&sq, -1.0, &opts()).unwrap();
    assert_eq!(out.len(), 1);
    assert!((out[0].area() - 64.0).abs() < 1e-9, "{out:?}");
    assert_eq!(out[0].len(), 4);
    assert_offset(std::slice::from_ref(&sq), &out, -1.0, 1e-3);
    // clockwise input keeps its sense
    let out = offset_polyline(&sq.reversed(), 1.0, &opts()).unwrap();
    assert!(!out[0].is_ccw());
}

#[test]
fn circle_stays_a_circle_and_vanishes_past_its_radius() {
    let c = Polyline::circle(Point::new(3.0, -2.0), 5.0);
    let out = offset_polyline(&c, -2.0, &opts()).unwrap();
    assert_eq!(out.len(), 1);
    assert!((out[0].area() - 9.0 * PI).abs() < 1e-9);
    assert!(out[0].vertices.iter().all(|v| v.bulge != 0.0));
    let out = offset_polyline(&c, 2.5, &opts()).unwrap();
    assert!((out[0].area() - 7.5 * 7.5 * PI).abs() < 1e-9);
    assert!(offset_polyline(&c, -5.5, &opts()).unwrap().is_empty());
}

#[test]
fn narrow_waist_splits_into_two() {
    // two 10×10 squares joined by a 2 mm wide neck
    let pts = [
        (0.0, 0.0),
        (10.0, 0.0),
        (10.0, 4.0),
        (14.0, 4.0),
        (14.0, 0.0),
        (24.0, 0.0),
        (24.0, 10.0),
        (14.0, 10.0),
        (14.0, 6.0),
        (10.0, 6.0),
        (10.0, 10.0),
        (0.0, 10.0),
    ];
    let p = Polyline::from_points(
        &pts.iter()
            .map(|&(x, y)| Point::new(x, y))
            .collect::<Vec<_>>(),
        true,
    );
    let out = offset_polyline(&p, -1.5, &opts()).unwrap();
    assert_eq!(out.len(), 2, "{out:?}");
    // two 7×7 squares, each with a rounded bump where the neck was
    assert!(out.iter().all(|o| o.area() > 49.0 && o.area() < 49.5));
    assert_offset(std::slice::from_ref(&p), &out, -1.5, 1e-3);
    assert_area(std::slice::from_ref(&p), &out, -1.5, 1e-3);
    // growing closes the notches into the outline
    let out = offset_polyline(&p, 2.5, &opts()).unwrap();
    assert_eq!(out.len(), 1);
    assert_offset(std::slice::from_ref(&p), &out, 2.5, 1e-3);
    assert_area(&[p], &out, 2.5, 1e-3);
}

#[test]
fn c_shape_grows_around_a_hole() {
    // a C whose opening closes when grown: the result has a clockwise hole
    let pts: Vec<Point> = vec![
        Point::new(0.0, 0.0),
        Point::new(20.0, 0.0),
        Point::new(20.0, 9.5),
        Point::new(18.0, 9.5),
        Point::new(18.0, 2.0),
        Point::new(2.0, 2.0),
        Point::new(2.0, 18.0),
        Point::new(18.0, 18.0),
        Point::new(18.0, 10.5),
        Point::new(20.0, 10.5),
        Point::new(20.0, 20.0),
        Point::new(0.0, 20.0),
    ];
    let p = Polyline::from_points(&pts, true);
    let out = offset_polyline(&p, 1.0, &opts()).unwrap();
    assert_eq!(out.len(), 2, "{out:?}");
    assert_eq!(out.iter().filter(|o| !o.is_ccw()).count(), 1);
    assert_offset(std::slice::from_ref(&p), &out, 1.0, 1e-3);
    assert_area(&[p], &out, 1.0, 1e-3);
}

fn star_strategy() -> impl Strategy<Value = (Vec<f64>, Vec<f64>, f64)> {
    (5usize..40).prop_flat_map(|n| {
        (
            prop::collection::vec(3.0f64..20.0, n),
            prop::collection::vec(-0.3f64..0.3, n),
            -8.0f64..8.0,
        )
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(offset_core::check::proptest_cases(1500)))]

    #[test]
    fn random_stars_keep_their_distance(rb in star_strategy(), use_arcs in any::<bool>()) {
        let (radii, bulges, d) = rb;
        prop_assume!(d.abs() > 1e-3);
        let p = if use_arcs {
            // bulges scaled so the arcs stay clear of the centre
            let b: Vec<f64> = bulges.iter().map(|b| b * 0.5).collect();
            star_with_arcs(Point::new(1.0, 2.0), &radii, &b)
        } else {
            star(Point::new(1.0, 2.0), &radii)
        };
        prop_assume!(offset_core::check::first_crossing(std::slice::from_ref(&p), 1e-3).is_none());
        let tol = 1e-3;
        let out = offset_polyline(&p, d, &OffsetOptions::default()).unwrap();
        assert_offset(std::slice::from_ref(&p), &out, d, tol);
        assert_area(&[p], &out, d, tol);
    }
}

#[test]
fn a_star_with_a_nearly_straight_arc_shrinks_without_crossing() {
    // found by the random stars: a bulge of 1.2e-5 beside a tooth
    let mut radii = vec![3.0; 29];
    radii[13..18].copy_from_slice(&[
        10.176503113941381,
        8.608822239497131,
        18.87449704573114,
        11.361447148839092,
        18.607234952261965,
    ]);
    let mut bulges = vec![0.0; 29];
    bulges[14] = 2.4503116154624668e-5 * 0.5;
    bulges[17] = 0.13535329394081574 * 0.5;
    let p = star_with_arcs(Point::new(1.0, 2.0), &radii, &bulges);
    let d = -2.452627890217215;
    let out = offset_polyline(&p, d, &OffsetOptions::default()).unwrap();
    assert_offset(std::slice::from_ref(&p), &out, d, 1e-3);
    assert_area(&[p], &out, d, 1e-3);
}

#[test]
fn a_star_with_a_nearly_straight_arc_grows_without_crossing() {
    // found by the random stars: a bulge of -2.8e-6 (radius 4e5) before a corner
    let mut radii = vec![3.0; 28];
    radii[14] = 8.736950766628619;
    radii[18..23].copy_from_slice(&[
        10.581193959040753,
        4.861098155715533,
        3.768513703549854,
        19.50181259832485,
        13.127433701719896,
    ]);
    let mut bulges = vec![0.0; 28];
    bulges[18] = -5.65373484258893e-6 * 0.5;
    bulges[20] = -0.2692121505394589 * 0.5;
    let p = star_with_arcs(Point::new(1.0, 2.0), &radii, &bulges);
    let d = 2.008575960074033;
    let out = offset_polyline(&p, d, &OffsetOptions::default()).unwrap();
    assert_offset(std::slice::from_ref(&p), &out, d, 1e-3);
    assert_area(&[p], &out, d, 1e-3);
}
