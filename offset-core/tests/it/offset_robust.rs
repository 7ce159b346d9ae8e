//! Robustness: dirty vertices, tiny segments, far coordinates, near-collapse, degenerate
//! distances, self-intersecting and non-finite input, wild input that must not panic, and
//! repeated pocket passes that must not pile up vertices.

use crate::common::*;
use offset_core::geom::{Point, Polyline, Region, Shape, Vertex};
use offset_core::offset::{
    offset_polyline, offset_region, offset_shape, Join, OffsetError, OffsetOptions,
};
use proptest::prelude::*;
use std::f64::consts::PI;

fn opts() -> OffsetOptions {
    OffsetOptions::default()
}

#[test]
fn collinear_duplicate_and_tiny_vertices_change_nothing() {
    let dirty = Polyline::new(
        vec![
            Vertex::new(0.0, 0.0, 0.0),
            Vertex::new(0.0, 0.0, 0.0),
            Vertex::new(5.0, 0.0, 0.0),
            Vertex::new(10.0, 0.0, 0.0),
            Vertex::new(10.0, 1e-9, 0.0),
            Vertex::new(10.0, 10.0, 0.0),
            Vertex::new(10.0, 10.0, 0.0),
            Vertex::new(3.0, 10.0, 0.0),
            Vertex::new(0.0, 10.0, 0.0),
            Vertex::new(0.0, 0.0, 0.0),
        ],
        true,
    );
    for d in [1.0, -1.0, 4.0] {
        let out = offset_polyline(&dirty, d, &opts()).unwrap();
        assert_eq!(out.len(), 1);
        let clean = offset_polyline(
            &Polyline::rect(Point::new(0.0, 0.0), Point::new(10.0, 10.0)),
            d,
            &opts(),
        )
        .unwrap();
        assert_eq!(out[0].len(), clean[0].len(), "{out:?}");
        assert!((out[0].area() - clean[0].area()).abs() < 1e-6);
        assert_offset(std::slice::from_ref(&dirty), &out, d, 1e-3);
    }
}

#[test]
fn far_coordinates_keep_their_precision() {
    let base = Point::new(1.0e7, -1.0e7);
    let sq = Polyline::rect(base, base + Point::new(40.0, 20.0));
    let out = offset_polyline(&sq, 2.0, &opts()).unwrap();
    assert_eq!(out.len(), 1);
    let expect = 800.0 + 120.0 * 2.0 + PI * 4.0;
    assert!(
        (out[0].area() - expect).abs() < 1e-3 * 130.0,
        "{}",
        out[0].area()
    );
    assert_offset(std::slice::from_ref(&sq), &out, 2.0, 1e-3);
    let out = offset_polyline(&sq, -9.0, &opts()).unwrap();
    assert!((out[0].area() - 22.0 * 2.0).abs() < 1e-3 * 50.0);
}

/// n points on a circle of radius 10, offset inward to within 1e-3 of the polygon's
/// inradius: the answer must be one tiny loop of area π·1e-6 (within 5 %) that passes the
/// checker, not nothing. Returns the polygon and its inradius.
fn dense_circle_closes_near_collapse(n: usize) -> (Polyline, f64) {
    let r = 10.0;
    let pts: Vec<Point> = (0..n)
        .map(|i| {
            let a = i as f64 / n as f64 * std::f64::consts::TAU;
            Point::new(r * a.cos(), r * a.sin())
        })
        .collect();
    let c = Polyline::from_points(&pts, true);
    // the polygon's inradius is r cos(π/n); leave 1e-3 of it
    let inr = r * (PI / n as f64).cos();
    let d = -(inr - 1e-3);
    let out = offset_polyline(&c, d, &opts()).unwrap();
    assert_eq!(
        out.len(),
        1,
        "n = {n}: the answer is a tiny circle, not nothing"
    );
    let a = out[0].area();
    assert!(
        (a - PI * 1e-6).abs() < 0.05 * PI * 1e-6,
        "n = {n}: area {a}"
    );
    assert_offset(std::slice::from_ref(&c), &out, d, 1e-3);
    (c, inr)
}

#[test]
fn dense_circle_offset_to_near_collapse_is_a_tiny_circle() {
    let (c, inr) = dense_circle_closes_near_collapse(1_000);
    assert!(offset_polyline(&c, -(inr + 1e-3), &opts())
        .unwrap()
        .is_empty());
}

#[test]
fn denser_circle_whose_tiny_offset_has_sides_shorter_than_epsilon_still_closes() {
    // 63,000 points: the tiny offset polygon's sides are 2e-3 tan(π/n) ≈ 0.997e-7 long,
    // just under the kernel's ε (1e-7 at the default tolerance), so segments two apart come
    // within ε of each other. Those near touches used to split every piece into its own run
    // and the stitching closed each after a few pieces into a loop with no area: empty.
    dense_circle_closes_near_collapse(63_000);
}

#[test]
fn rectangle_offset_by_half_its_width_is_empty() {
    // the result degenerates to the centre line, which encloses nothing: no loop
    let r = Polyline::rect(Point::new(0.0, 0.0), Point::new(10.0, 4.0));
    assert!(offset_polyline(&r, -2.0, &opts()).unwrap().is_empty());
    let out = offset_polyline(&r, -1.999, &opts()).unwrap();
    assert_eq!(out.len(), 1);
    assert!((out[0].area() - 6.002 * 0.002).abs() < 1e-9);
    assert!(offset_polyline(&r, -50.0, &opts()).unwrap().is_empty());
    let region = Region::new(r, vec![]);
    assert!(offset_region(&region, -2.5, &opts()).unwrap().is_empty());
}

#[test]
fn bad_input_is_an_error() {
    let bow = Polyline::from_points(
        &[
            Point::new(0.0, 0.0),
            Point::new(10.0, 10.0),
            Point::new(10.0, 0.0),
            Point::new(0.0, 10.0),
        ],
        true,
    );
    match offset_polyline(&bow, 1.0, &opts()) {
        Err(OffsetError::SelfIntersecting { path: 0, at }) => {
            assert!(at.dist(Point::new(5.0, 5.0)) < 1e-9)
        }
        other => panic!("{other:?}"),
    }
    let sq = Polyline::rect(Point::new(0.0, 0.0), Point::new(10.0, 10.0));
    let mut nan = sq.clone();
    nan.vertices[2].y = f64::NAN;
    assert_eq!(
        offset_polyline(&nan, 1.0, &opts()),
        Err(OffsetError::NotFinite { path: 0, vertex: 2 })
    );
    assert!(matches!(
        offset_polyline(&sq, f64::INFINITY, &opts()),
        Err(OffsetError::BadDistance(_))
    ));
    let bad_tol = OffsetOptions {
        tolerance: 0.0,
        ..Default::default()
    };
    assert!(matches!(
        offset_polyline(&sq, 1.0, &bad_tol),
        Err(OffsetError::BadTolerance(_))
    ));
    // an island crossing the outer names the island's path
    let region = Region::new(
        sq.clone(),
        vec![Polyline::rect(Point::new(5.0, 5.0), Point::new(15.0, 8.0))],
    );
    assert!(matches!(
        offset_region(&region, -1.0, &opts()),
        Err(OffsetError::SelfIntersecting { .. })
    ));
}

fn gear_with_islands(teeth: usize, n: usize) -> Region {
    let pts: Vec<Point> = (0..n)
        .map(|i| {
            let a = i as f64 / n as f64 * std::f64::consts::TAU;
            let r = 40.0 + 3.0 * (teeth as f64 * a).sin();
            Point::new(r * a.cos(), r * a.sin())
        })
        .collect();
    let islands = (0..5)
        .map(|k| {
            let a = k as f64 / 5.0 * std::f64::consts::TAU;
            Polyline::circle(Point::new(a.cos(), a.sin()) * 22.0, 4.0)
        })
        .collect();
    Region::new(Polyline::from_points(&pts, true), islands)
}

#[test]
fn repeated_pocket_passes_do_not_pile_up_vertices() {
    let region = gear_with_islands(12, 600);
    let mut current = vec![region.clone()];
    let mut counts = Vec::new();
    for pass in 0..20 {
        let mut next = Vec::new();
        for r in &current {
            next.extend(offset_region(r, -0.8, &opts()).unwrap());
        }
        let verts: usize = next
            .iter()
            .flat_map(|r| r.boundaries())
            .map(|p| p.len())
            .sum();
        counts.push(verts);
        // each pass is itself an offset of the previous one
        let input: Vec<Polyline> = current
            .iter()
            .flat_map(|r| r.boundaries().cloned())
            .collect();
        assert_offset(&input, &region_paths(&next), -0.8, 1e-3);
        current = next;
        if current.is_empty() {
            assert!(pass > 5);
            break;
        }
    }
    for w in counts.windows(2) {
        assert!(w[1] <= w[0] + 4, "vertex count grew: {counts:?}");
    }
    assert!(counts.last() <= counts.first(), "{counts:?}");
}

fn wild_f64() -> impl Strategy<Value = f64> {
    prop_oneof![
        -1e3f64..1e3,
        -1e9f64..1e9,
        -1e-6f64..1e-6,
        Just(0.0),
        Just(1e300),
        Just(-1e-300),
        Just(f64::NAN),
        Just(f64::INFINITY),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(offset_core::check::proptest_cases(600)))]

    #[test]
    fn wild_input_never_panics(
        verts in prop::collection::vec((wild_f64(), wild_f64(), prop_oneof![Just(0.0), -3.0f64..3.0, wild_f64()]), 0..12),
        closed in any::<bool>(),
        d in wild_f64(),
        tol in prop_oneof![Just(1e-3), wild_f64()],
        join in prop_oneof![Just(Join::Round), Just(Join::Miter), Just(Join::Chamfer)],
    ) {
        let p = Polyline::new(verts.iter().map(|&(x, y, b)| Vertex::new(x, y, b)).collect(), closed);
        let o = OffsetOptions { join, tolerance: tol, miter_limit: 2.0 };
        let _ = offset_polyline(&p, d, &o);
        let _ = offset_shape(&Shape::new(vec![p.clone(), Polyline::rect(Point::new(-5.0, -5.0), Point::new(5.0, 5.0))]), d, &o);
    }
}

#[test]
fn loop_touching_itself_at_one_vertex_offsets_both_ways() {
    // two squares meeting at one corner, drawn as one loop through that corner twice (what
    // a pocket pass on round numbers can hand the next): a touch, not a crossing
    let p = Point::new;
    let pl = Polyline::from_points(
        &[
            p(0.0, 0.0),
            p(10.0, 0.0),
            p(10.0, 10.0),
            p(20.0, 10.0),
            p(20.0, 20.0),
            p(10.0, 20.0),
            p(10.0, 10.0),
            p(0.0, 10.0),
        ],
        true,
    );
    let input = std::slice::from_ref(&pl);
    let out = offset_polyline(&pl, -1.0, &opts()).unwrap();
    assert_eq!(out.len(), 2, "the two squares shrink apart");
    assert!(out.iter().all(|l| (l.area() - 64.0).abs() < 1e-9));
    assert_offset(input, &out, -1.0, 1e-3);
    // grown, they overlap round the shared corner: two 10 × 10 squares grown by 1 less the
    // 2 × 2 square there with the two corners outside both rounded joins
    let out = offset_polyline(&pl, 1.0, &opts()).unwrap();
    assert_eq!(out.len(), 1);
    let want = 2.0 * (100.0 + 40.0 + PI) - (2.0 + PI / 2.0);
    assert!((out[0].area() - want).abs() < 1e-9, "{}", out[0].area());
    assert_offset(input, &out, 1.0, 1e-3);
}
