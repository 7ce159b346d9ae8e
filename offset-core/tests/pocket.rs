//! Pocketing: the swept tool covers every reachable part of the pocket and never touches a
//! wall or an island, on pockets whose islands merge, split the pocket, or vanish into the
//! wall; checked by rasterising the pocket and the tool's swept disc at 0.1 mm.

mod pocket_support;

use offset_core::geom::{Point, Polyline, Region, Shape};
use offset_core::ops::{pocket, pocket_with, OpError, PocketParams, Stepover};
use offset_core::toolpath::{Move, Tool, P3};
use pocket_support::{check_coverage, clipper_offset};

fn rect(x0: f64, y0: f64, x1: f64, y1: f64) -> Polyline {
    Polyline::rect(Point::new(x0, y0), Point::new(x1, y1))
}

/// Islands 2 mm apart: their offsets merge into one island.
fn merging() -> Shape {
    Shape::new(vec![
        rect(0.0, 0.0, 60.0, 40.0),
        Polyline::circle(Point::new(24.0, 20.0), 5.0),
        Polyline::circle(Point::new(36.0, 20.0), 5.0),
    ])
}

/// A bar across the middle: the passes split into a top and a bottom part.
fn splitting() -> Shape {
    Shape::new(vec![
        rect(0.0, 0.0, 60.0, 40.0),
        rect(8.0, 14.0, 52.0, 26.0),
    ])
}

/// An island 3 mm from the wall (less than the tool): it joins the wall and vanishes as an island.
fn vanishing() -> Shape {
    Shape::new(vec![
        rect(0.0, 0.0, 50.0, 30.0),
        Polyline::circle(Point::new(8.0, 15.0), 5.0),
        rect(30.0, 10.0, 36.0, 16.0),
    ])
}

/// An L with a narrow arm and a sharp corner: necks and corners where the step-over leaves cusps.
fn l_shape() -> Shape {
    Shape::new(vec![Polyline::from_points(
        &[
            Point::new(0.0, 0.0),
            Point::new(50.0, 0.0),
            Point::new(50.0, 9.0),
            Point::new(14.0, 9.0),
            Point::new(14.0, 40.0),
            Point::new(0.0, 40.0),
        ],
        true,
    )])
}

fn params(stepover: Stepover) -> PocketParams {
    PocketParams {
        stepover,
        cut: offset_core::ops::Cutting {
            tool: Tool::flat(6.0),
            depth: 2.0,
            stepdown: 1.0,
            tolerance: 1e-3,
            ..PocketParams::default().cut
        },
    }
}

fn check(name: &str, shape: &Shape, p: &PocketParams, use_kernel: bool) {
    let tp = if use_kernel {
        pocket(shape, p).unwrap()
    } else {
        let tol = p.cut.tolerance;
        pocket_with(shape, p, &|r: &Region, d: f64| clipper_offset(r, d, tol)).unwrap()
    };
    let region = &shape.regions()[0];
    let r = p.cut.tool.radius();
    // both depth passes reach the bottom, and nothing goes below it
    let b = tp.bounds().unwrap();
    assert!((b.min.z + p.cut.depth).abs() < 1e-9, "{name}: {b:?}");
    // the chord tolerance of Clipper's round joins and of the pass arcs
    let c = check_coverage(region, &tp, r, -p.cut.depth, 0.1, 0.01);
    assert_eq!(
        c.gouges, 0,
        "{name}: tool enters a wall or island at {:?}",
        c.first_gouge
    );
    assert_eq!(
        c.uncut, 0,
        "{name}: {} of {} reachable cells uncut, e.g. at {:?}",
        c.uncut, c.cells, c.first_uncut
    );
    // rapids only ever at the safe height or straight down onto a start
    tp.walk(P3::default(), |from, m, to| {
        if let Move::Rapid { .. } = m {
            assert!(
                to.z >= p.cut.safe_z - 1e-9 || (from.xy().dist(to.xy()) < 1e-9),
                "{name}: rapid through material to {to:?}"
            );
        }
    });
}

#[test]
fn pockets_with_islands_are_covered_without_gouging_clipper_offsets() {
    for so in [Stepover::Percent(40.0), Stepover::Percent(90.0)] {
        let p = params(so);
        check("merging", &merging(), &p, false);
        check("splitting", &splitting(), &p, false);
        check("vanishing", &vanishing(), &p, false);
        check("l-shape", &l_shape(), &p, false);
    }
}

#[test]
fn pockets_with_islands_are_covered_without_gouging_kernel_offsets() {
    for so in [Stepover::Percent(40.0), Stepover::Percent(90.0)] {
        let p = params(so);
        check("merging", &merging(), &p, true);
        check("splitting", &splitting(), &p, true);
        check("vanishing", &vanishing(), &p, true);
        check("l-shape", &l_shape(), &p, true);
    }
}

#[test]
fn merging_islands_become_one_pass_loop() {
    let shape = merging();
    let p = params(Stepover::Percent(40.0));
    let first = clipper_offset(&shape.regions()[0], -3.0, 1e-3).unwrap();
    assert_eq!(first.len(), 1);
    assert_eq!(first[0].islands.len(), 1, "the two islands' offsets merge");
    let split = clipper_offset(&splitting().regions()[0], -3.0 - 2.4, 1e-3).unwrap();
    assert_eq!(split.len(), 2, "the bar splits the pocket");
    let van = clipper_offset(&vanishing().regions()[0], -3.0, 1e-3).unwrap();
    assert_eq!(
        van[0].islands.len(),
        1,
        "the island by the wall joins the wall"
    );
    let _ = p;
}

#[test]
fn conventional_runs_the_other_way() {
    let shape = Shape::new(vec![rect(0.0, 0.0, 20.0, 20.0)]);
    let mut p = params(Stepover::Percent(40.0));
    let off = |r: &Region, d: f64| clipper_offset(r, d, 1e-3);
    let climb = pocket_with(&shape, &p, &off).unwrap();
    p.cut.climb = false;
    let conv = pocket_with(&shape, &p, &off).unwrap();
    // signed area swept by the first loop's cutting moves: ccw for climb on a wall
    let area = |tp: &offset_core::Toolpath| {
        let mut a = 0.0;
        let mut n = 0;
        tp.walk(P3::default(), |from, m, to| {
            if matches!(m, Move::Linear { .. }) && from.z == to.z && to.z < 0.0 && n < 4 {
                a += from.xy().cross(to.xy());
                n += 1;
            }
        });
        a
    };
    assert!(area(&climb) > 0.0 && area(&conv) < 0.0);
}

#[test]
fn bad_parameters_and_a_tool_too_big_are_errors() {
    let shape = Shape::new(vec![rect(0.0, 0.0, 4.0, 4.0)]);
    let off = |r: &Region, d: f64| clipper_offset(r, d, 1e-3);
    let e = pocket_with(&shape, &params(Stepover::Percent(40.0)), &off).unwrap_err();
    assert!(matches!(e, OpError::Empty(_)), "{e}");
    let mut p = params(Stepover::Mm(7.0));
    let e = pocket_with(&Shape::new(vec![rect(0.0, 0.0, 40.0, 40.0)]), &p, &off).unwrap_err();
    assert!(e.to_string().contains("more than the tool diameter"), "{e}");
    p.stepover = Stepover::Mm(1.0);
    let e = pocket_with(&Shape::new(vec![]), &p, &off).unwrap_err();
    assert!(e.to_string().contains("closed outlines"), "{e}");
}

#[test]
fn passes_that_touch_the_wall_exactly_still_plan_and_cover() {
    // with a 3 mm tool at 1.2 mm steps, the merged islands' sixth pass meets the wall's
    // exactly (both 7.5 mm from the walls): a tangent contact the pocket steps around
    let shape = Shape::new(vec![
        rect(0.0, 0.0, 60.0, 40.0),
        Polyline::circle(Point::new(24.0, 20.0), 5.0),
        Polyline::circle(Point::new(36.0, 20.0), 5.0),
    ]);
    let p = PocketParams {
        stepover: Stepover::Percent(40.0),
        cut: offset_core::ops::Cutting {
            tool: Tool::flat(3.0),
            depth: 1.0,
            ..params(Stepover::Percent(40.0)).cut
        },
    };
    check("touching", &shape, &p, true);
}
