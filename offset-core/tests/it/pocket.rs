//! Pocketing: the swept tool covers every reachable part of the pocket and never touches a
//! wall or an island, on pockets whose islands merge, split the pocket, or vanish into the
//! wall; checked by rasterising the pocket and the tool's swept disc at 0.1 mm. Entries
//! (helix, ramp) are cutting moves like any other, so the same check holds them to the
//! tool radius from every wall and island; and no entry descends steeper than the ramp
//! angle or goes straight down into the material.

use crate::pocket_support;

use offset_core::geom::{Point, Polyline, Region, Shape};
use offset_core::ops::{pocket, pocket_with, Entry, OpError, PocketParams, Stepover};
use offset_core::toolpath::{Move, Tool, Toolpath, P3};
use pocket_support::{check_coverage, clipper_offset, descending_arcs, descents, disjoint_arc};

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
    // nothing goes below the bottom, and every pass depth (not just the last) clears the
    // whole pocket without touching a wall or island
    let b = tp.bounds().unwrap();
    assert!((b.min.z + p.cut.depth).abs() < 1e-9, "{name}: {b:?}");
    // the pass depths worked out here, not by the planner's own function: equal steps of
    // at most the stepdown down to the depth
    let n = (p.cut.depth / p.cut.stepdown).ceil() as usize;
    for z in (1..=n).map(|k| -p.cut.depth * k as f64 / n as f64) {
        // the chord tolerance of Clipper's round joins and of the pass arcs
        let c = check_coverage(region, &tp, r, z, 0.1, 0.01);
        assert_eq!(
            c.gouges, 0,
            "{name}: at z {z} the tool enters a wall or island at {:?}",
            c.first_gouge
        );
        assert_eq!(
            c.uncut, 0,
            "{name}: at z {z}, {} of {} reachable cells uncut, e.g. at {:?}",
            c.uncut, c.cells, c.first_uncut
        );
    }
    check_entries(name, &tp, p);
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

/// Entries other than plunges never go straight down into the material and never descend
/// steeper than the ramp angle; plunges are what was asked for, or warned about.
fn check_entries(name: &str, tp: &Toolpath, p: &PocketParams) {
    assert_eq!(
        disjoint_arc(tp),
        None,
        "{name}: an arc that starts off its circle"
    );
    let d = descents(tp);
    let slope = p.cut.ramp_angle.to_radians().tan();
    if p.cut.entry == Entry::Plunge {
        assert!(d.plunges > 0, "{name}: plunge entries asked for: {d:?}");
        assert!(tp.warnings.is_empty(), "{name}: {:?}", tp.warnings);
        return;
    }
    assert!(
        d.steepest <= slope * (1.0 + 1e-9),
        "{name}: an entry descends {} per mm at {:?}, steeper than the ramp angle ({slope})",
        d.steepest,
        d.steepest_at
    );
    if tp.warnings.is_empty() {
        assert_eq!(
            d.plunges, 0,
            "{name}: the tool went straight down into the material at {:?}",
            d.first_plunge
        );
    } else {
        assert!(
            d.plunges > 0,
            "{name}: a warning with no plunge: {:?}",
            tp.warnings
        );
    }
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

/// The shapes' premises, on Clipper2's offsets (the reference the pocket tests above plan
/// with): the two islands' offsets merge, the bar splits the pocket, the island by the wall
/// joins the wall. (This checks the test shapes, not the pocket planner.)
#[test]
fn the_test_shapes_merge_split_and_join_as_named_under_clipper2() {
    let first = clipper_offset(&merging().regions()[0], -3.0, 1e-3).unwrap();
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

fn with_entry(mut p: PocketParams, entry: Entry) -> PocketParams {
    p.cut.entry = entry;
    p
}

#[test]
fn pockets_entered_by_ramps_are_covered_without_gouging() {
    for so in [Stepover::Percent(40.0), Stepover::Percent(90.0)] {
        let p = with_entry(params(so), Entry::Ramp);
        check("merging, ramps", &merging(), &p, true);
        check("splitting, ramps", &splitting(), &p, true);
        check("vanishing, ramps", &vanishing(), &p, true);
        check("l-shape, ramps", &l_shape(), &p, true);
    }
}

#[test]
fn pockets_entered_by_plunges_go_straight_down_without_a_warning() {
    let p = with_entry(params(Stepover::Percent(40.0)), Entry::Plunge);
    check("merging, plunges", &merging(), &p, true);
    check("l-shape, plunges", &l_shape(), &p, true);
}

#[test]
fn helix_entries_turn_on_the_diameter_asked_for_inside_the_pocket() {
    let mut p = params(Stepover::Percent(40.0));
    p.cut.helix_diameter = 4.0;
    check("splitting, helix 4 mm", &splitting(), &p, true);
    let tp = pocket(&splitting(), &p).unwrap();
    let arcs = descending_arcs(&tp);
    assert!(!arcs.is_empty(), "no helix");
    for (c, r) in arcs {
        assert!((r - 2.0).abs() < 1e-9, "a helix turn of radius {r}");
        // the helix's circle lies inside the area the tool centre may visit
        let wall = Polyline::rect(Point::new(0.0, 0.0), Point::new(60.0, 40.0));
        assert!(wall.distance_to(c) >= 3.0 + 2.0 - 1e-9, "centre {c:?}");
    }
}

#[test]
fn the_default_helix_is_the_tool_diameter_and_turns_the_climb_way() {
    let p = params(Stepover::Percent(40.0));
    let tp = pocket(&Shape::new(vec![rect(0.0, 0.0, 40.0, 30.0)]), &p).unwrap();
    let mut turns = 0;
    tp.walk(P3::default(), |from, m, to| {
        if let Move::Arc { center, ccw, .. } = m {
            if to.z < from.z - 1e-12 {
                assert!((from.xy().dist(*center) - 3.0).abs() < 1e-9);
                assert!(*ccw, "climb: passes round the walls counter-clockwise");
                turns += 1;
            }
        }
    });
    // a half turn of radius 3 mm is 9.42 mm long and goes down at most 9.42 tan 3° = 0.49
    // mm: 1 mm a pass takes 3 half turns, made 4 to end where the pass starts; two passes
    assert_eq!(turns, 8);
    assert!(tp.warnings.is_empty());
}

#[test]
fn a_slot_too_narrow_for_a_helix_is_ramped_along_its_pass() {
    // 7.2 mm wide for a 6 mm tool: the tool centre has a 1.2 mm strip, no room for a
    // helix of even 3 mm; the pass round the strip is 2 × 53 mm long
    let shape = Shape::new(vec![rect(0.0, 0.0, 60.0, 7.2)]);
    let p = params(Stepover::Percent(40.0));
    check("slot", &shape, &p, true);
    let tp = pocket(&shape, &p).unwrap();
    assert!(
        descending_arcs(&tp).is_empty(),
        "a helix in a slot too narrow"
    );
    let d = descents(&tp);
    assert!(d.ramps > 0 && d.plunges == 0, "{d:?}");
    let strip = Polyline::rect(Point::new(3.0, 3.0), Point::new(57.0, 4.2));
    tp.walk(P3::default(), |from, m, to| {
        if matches!(m, Move::Linear { .. }) && to.z < from.z - 1e-12 && to.z < -1e-12 {
            assert!(
                strip.distance_to(to.xy()) < 1e-6,
                "a ramp off the pass at {to:?}"
            );
        }
    });
}

#[test]
fn a_pocket_too_small_to_ramp_plunges_and_says_so() {
    // a 6.6 mm hole for a 6 mm tool: the tool centre has a circle of 0.6 mm to go round
    let shape = Shape::new(vec![Polyline::circle(Point::new(0.0, 0.0), 3.3)]);
    let p = params(Stepover::Percent(40.0));
    let tp = pocket(&shape, &p).unwrap();
    assert_eq!(tp.warnings.len(), 1, "{:?}", tp.warnings);
    assert!(
        tp.warnings[0].contains("straight down into the material 2 times"),
        "{}",
        tp.warnings[0]
    );
    let d = descents(&tp);
    assert_eq!(d.plunges, 2, "{d:?}");
    check_entries("small hole", &tp, &p);
}

/// Issue 13's gear, r = 60 + 4 sin 24θ + 3 sin 5θ, at `n` points.
fn gear(n: usize) -> Polyline {
    let pts: Vec<Point> = (0..n)
        .map(|i| {
            let a = std::f64::consts::TAU * i as f64 / n as f64;
            let r = 60.0 + 4.0 * (24.0 * a).sin() + 3.0 * (5.0 * a).sin();
            Point::new(r * a.cos(), r * a.sin())
        })
        .collect();
    Polyline::from_points(&pts, true)
}

#[test]
fn the_issue_13_gear_of_100000_vertices_pockets() {
    // as points (the hard case: the pocket's passes are offsets of offsets of a polygon
    // whose 2 mm shrink once carried a back-step the kernel refused), 3 mm tool, 40 %
    let shape = Shape::new(vec![gear(100_000)]);
    let p = PocketParams {
        stepover: Stepover::Percent(40.0),
        cut: offset_core::ops::Cutting {
            tool: Tool::flat(3.0),
            depth: 1.0,
            stepdown: 1.0,
            ..Default::default()
        },
    };
    let tp = pocket(&shape, &p).unwrap();
    let b = tp.bounds().unwrap();
    assert!((b.min.z + 1.0).abs() < 1e-12);
    // the passes reach from the wall (the gear dips to r = 53.1) to the middle
    assert!(b.max.x > 60.0 && b.min.x < -50.0, "{b:?}");
    assert!(tp.warnings.is_empty(), "{:?}", tp.warnings);
    check_entries("100 000-vertex gear", &tp, &p);
    // every cut keeps the tool radius off the wall
    let wall = &shape.paths[0];
    let mut far = Vec::new();
    tp.walk(P3::default(), |_, m, to| {
        if matches!(m, Move::Linear { .. } | Move::Arc { .. }) && to.z < 0.0 {
            far.push(to.xy());
        }
    });
    for q in far.iter().step_by(997) {
        assert!(
            wall.contains(*q) && wall.distance_to(*q) >= 1.5 - 0.01,
            "{q:?}"
        );
    }
}
