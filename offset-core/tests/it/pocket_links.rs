//! Links at depth: on the plate with two islands and on an L with a narrow arm, the pocket
//! retracts to the safe height fewer times than with every link at the safe height (both
//! counts printed), and the simulation shows every link moving through air only: no
//! material removed by a link, no gouge, no rapid through material, nothing left.

use crate::common::{level_at_any, lift_heights};
use offset_core::cutsim::{simulate, MoveKind, Part, SimOptions, Stock};
use offset_core::geom::{Point, Polyline, Shape};
use offset_core::ops::{pocket, pocket_safe_links, Cutting, PocketParams, Stepover};
use offset_core::toolpath::Tool;

fn plate() -> Shape {
    Shape::new(vec![
        Polyline::rect(Point::new(0.0, 0.0), Point::new(120.0, 80.0)),
        Polyline::circle(Point::new(40.0, 40.0), 10.0),
        Polyline::rect(Point::new(75.0, 25.0), Point::new(95.0, 55.0)),
    ])
}

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

fn check(name: &str, shape: &Shape, depth: f64) {
    let p = PocketParams {
        cut: Cutting {
            tool: Tool::flat(6.0),
            depth,
            stepdown: 1.0,
            ..Cutting::default()
        },
        stepover: Stepover::Percent(40.0),
    };
    let low = pocket(shape, &p).unwrap();
    let high = pocket_safe_links(shape, &p).unwrap();
    crate::common::assert_fewer_retracts(name, &low, &high);
    let b = shape.bounds();
    let o = SimOptions {
        cell: 0.1,
        part: Some(Part {
            clear: shape.regions(),
            floor: -depth,
        }),
        ..SimOptions::new(Tool::flat(6.0))
    };
    let rep = simulate(&low, &Stock::block(b.min, b.max, 0.0), &o).unwrap();
    assert_eq!(rep.gouges, 0, "{name}: gouge at {:?}", rep.first_gouge);
    assert_eq!(rep.left, 0, "{name}: material left at {:?}", rep.first_left);
    assert_eq!(rep.rapid_cuts, 0, "{name}: a rapid through material");
    // a link: a level feed move at a lift height (a level's top plus the lift); it may
    // brush a finished wall (the probes read just outside the tool) but removes nothing
    let levels = lift_heights(depth);
    let mut links = 0;
    for m in &rep.moves {
        let at_lift = level_at_any(m, &levels);
        if m.kind == MoveKind::Cut && at_lift {
            links += 1;
            assert!(
                m.removed == 0.0 && m.gouges == 0,
                "{name}: the link {:?} → {:?} cuts {} mm³",
                m.from,
                m.to,
                m.removed
            );
        }
    }
    assert!(links > 0, "{name}: no link at depth");
}

#[test]
fn the_plate_with_two_islands_retracts_less_and_links_through_air() {
    check("plate 120 × 80, two islands, 3 levels", &plate(), 3.0);
}

#[test]
fn the_l_with_a_narrow_arm_retracts_less_and_links_through_air() {
    check("L 50 × 40, arm 9 wide, 2 levels", &l_shape(), 2.0);
}
