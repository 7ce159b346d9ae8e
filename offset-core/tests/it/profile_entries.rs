//! Profile entries: without a lead-in the tool ramps down along its own loop, with tabs it
//! ramps in the gap before the first tab and down again after every tab, a long enough
//! lead-in takes it down by itself, a spiral goes down lap after lap without stopping, and
//! open paths are ramped back and forth; never steeper than the ramp angle, never straight
//! down into the material unless asked (or warned), never nearer the part than the tool
//! radius.

use crate::pocket_support;

use offset_core::geom::{Point, Polyline, Shape};
use offset_core::ops::{profile, Cutting, Entry, ProfileParams, Side};
use offset_core::toolpath::{Move, Tool, Toolpath, P3};
use pocket_support::descents;

fn part() -> Polyline {
    Polyline::rect(Point::new(0.0, 0.0), Point::new(40.0, 30.0))
}

fn params(side: Side) -> ProfileParams {
    ProfileParams {
        side,
        cut: Cutting {
            tool: Tool::flat(3.0),
            depth: 3.0,
            stepdown: 1.0,
            ..Default::default()
        },
        ..Default::default()
    }
}

/// No ramp steeper than the angle, no plunge into material, no warning; and every cutting
/// move below the stock top keeps the tool radius off the part (outside it).
fn check(name: &str, tp: &Toolpath, p: &ProfileParams, outline: &Polyline) {
    let d = descents(tp);
    let slope = p.cut.ramp_angle.to_radians().tan();
    assert!(
        d.steepest <= slope * (1.0 + 1e-9),
        "{name}: a descent of {} per mm at {:?}",
        d.steepest,
        d.steepest_at
    );
    assert_eq!(d.plunges, 0, "{name}: a plunge at {:?}", d.first_plunge);
    assert!(d.ramps > 0, "{name}: no ramp");
    assert!(tp.warnings.is_empty(), "{name}: {:?}", tp.warnings);
    // every arc starts where the tool is: as far from its centre as its end
    tp.walk(P3::default(), |from, m, to| {
        if let Move::Arc { center, .. } = m {
            let (r0, r1) = (from.xy().dist(*center), to.xy().dist(*center));
            assert!(
                (r0 - r1).abs() < 1e-6,
                "{name}: an arc from {from:?} to {to:?} about {center:?}"
            );
        }
    });
    let r = p.cut.tool.radius();
    let mut one = Toolpath::new("");
    tp.walk(P3::default(), |from, m, to| {
        if matches!(m, Move::Linear { .. } | Move::Arc { .. }) && (from.z < 0.0 || to.z < 0.0) {
            one.moves = vec![m.clone()];
            for q in one.sample(from, 0.05) {
                let near = outline.distance_to(q.xy());
                assert!(
                    near >= r - 1e-6 && !outline.contains(q.xy()),
                    "{name}: the tool comes {near} mm from the part at {q:?}"
                );
            }
        }
    });
}

#[test]
fn an_outside_profile_ramps_down_its_own_loop() {
    let p = params(Side::Outside);
    let tp = profile(&Shape::new(vec![part()]), &p).unwrap();
    check("outside", &tp, &p, &part());
    // in place from pass to pass: the only rapids are the approach and the retract
    let rapids = tp
        .moves
        .iter()
        .filter(|m| matches!(m, Move::Rapid { .. }))
        .count();
    assert_eq!(rapids, 3, "{:?}", tp.moves);
    assert!((tp.bounds().unwrap().min.z + 3.0).abs() < 1e-12);
}

#[test]
fn tabs_are_ramped_into_before_the_first_and_out_of_after_each() {
    let mut p = params(Side::Outside);
    p.tabs = 4;
    p.tab_width = 2.0;
    p.tab_height = 1.0;
    let tp = profile(&Shape::new(vec![part()]), &p).unwrap();
    check("tabs", &tp, &p, &part());
    // the passes below the tab tops rise to them, four times each
    let mut rises = 0;
    tp.walk(P3::default(), |from, m, to| {
        if matches!(m, Move::Linear { .. })
            && from.xy().dist(to.xy()) < 1e-12
            && to.z > from.z
            && (to.z + 2.0).abs() < 1e-9
        {
            rises += 1;
        }
    });
    assert_eq!(rises, 4, "one pass below the tab tops at Z-2");
}

#[test]
fn a_long_lead_in_takes_the_tool_down_by_itself() {
    // a quarter circle of radius 60 is 94 mm long: 4.9 mm down at 3°, more than the depth
    let mut p = params(Side::Outside);
    p.lead_in = 60.0;
    p.lead_out = 2.0;
    let tp = profile(&Shape::new(vec![part()]), &p).unwrap();
    check("long lead-in", &tp, &p, &part());
    // every descent that moves across is the lead-in arc (radius 60), from the stock top
    tp.walk(P3::default(), |from, m, to| {
        if to.z < from.z - 1e-12 && to.z < -1e-12 && from.xy() != to.xy() {
            let Move::Arc { center, .. } = m else {
                panic!("a descent that is no lead-in: {m:?}");
            };
            assert!((from.xy().dist(*center) - 60.0).abs() < 1e-9);
            assert_eq!(from.z, 0.0);
        }
    });
    // a short lead-in goes down as far as it can, and a zig-zag along the loop on
    p.lead_in = 2.0;
    let tp = profile(&Shape::new(vec![part()]), &p).unwrap();
    check("short lead-in", &tp, &p, &part());
}

#[test]
fn a_spiral_goes_down_lap_after_lap_without_stopping() {
    let mut p = params(Side::Outside);
    p.cut.spiral = true;
    let tp = profile(&Shape::new(vec![part()]), &p).unwrap();
    check("spiral", &tp, &p, &part());
    let rapids = tp
        .moves
        .iter()
        .filter(|m| matches!(m, Move::Rapid { .. }))
        .count();
    assert_eq!(rapids, 3, "approach, over the start, retract");
    // a lap of the offset outline (about 146 mm) goes down at most the step-down
    let lap = 2.0 * (43.0 + 33.0) - (4.0 - std::f64::consts::PI) * 1.5 * 1.5 / 1.5 * 2.0;
    let mut xy = 0.0;
    let mut dz = 0.0;
    tp.walk(P3::default(), |from, m, to| {
        if matches!(m, Move::Linear { .. } | Move::Arc { .. }) && to.z < from.z && from.z <= 0.0 {
            xy += match m {
                Move::Arc { center, ccw, .. } => {
                    offset_core::toolpath::arc_segment(from.xy(), to.xy(), *center, *ccw).length()
                }
                _ => from.xy().dist(to.xy()),
            };
            dz += from.z - to.z;
        }
    });
    assert!((dz - 3.0).abs() < 1e-9, "{dz}");
    assert!(dz / xy <= 1.0 / (lap * 0.98), "{dz} mm down over {xy} mm");
    assert!(tp.warnings.is_empty());
}

#[test]
fn open_paths_are_ramped_back_and_forth() {
    let line = Polyline::from_points(
        &[
            Point::new(0.0, 0.0),
            Point::new(30.0, 0.0),
            Point::new(30.0, 20.0),
        ],
        false,
    );
    let p = params(Side::On);
    let tp = profile(&Shape::new(vec![line.clone()]), &p).unwrap();
    let d = descents(&tp);
    assert_eq!(d.plunges, 0, "{d:?}");
    assert!(d.steepest <= p.cut.ramp_angle.to_radians().tan() * (1.0 + 1e-9));
    tp.walk(P3::default(), |_, m, to| {
        if matches!(m, Move::Linear { .. } | Move::Arc { .. }) {
            assert!(line.distance_to(to.xy()) < 1e-9, "off the path at {to:?}");
        }
    });
}

#[test]
fn plunge_entries_keep_to_the_old_way() {
    let mut p = params(Side::Outside);
    p.cut.entry = Entry::Plunge;
    let tp = profile(&Shape::new(vec![part()]), &p).unwrap();
    let d = descents(&tp);
    assert_eq!(d.plunges, 3, "one a pass: {d:?}");
    assert_eq!(d.ramps, 0);
    assert!(tp.warnings.is_empty());
}

#[test]
fn a_hole_too_small_to_ramp_in_is_plunged_with_a_warning() {
    // a 3.2 mm hole for a 3 mm tool: the tool centre goes round a circle 0.6 mm long
    let hole = Polyline::circle(Point::new(0.0, 0.0), 1.6);
    let p = params(Side::Inside);
    let tp = profile(&Shape::new(vec![hole]), &p).unwrap();
    assert_eq!(tp.warnings.len(), 1, "{:?}", tp.warnings);
    assert!(
        tp.warnings[0].contains("straight down"),
        "{}",
        tp.warnings[0]
    );
    assert_eq!(descents(&tp).plunges, 3);
}

#[test]
fn tabs_with_lead_ins_and_outs_leave_every_move_joined() {
    // the shape of the GRBL end-to-end test: the ramp after the last tab goes on along the
    // loop's start and must come back before the lead-out
    let shape = Shape::new(vec![
        Polyline::rect(Point::new(0.0, 0.0), Point::new(40.0, 30.0)),
        Polyline::circle(Point::new(20.0, 15.0), 5.0),
    ]);
    for side in [Side::Outside, Side::Inside] {
        let mut p = params(side);
        p.cut.depth = 2.0;
        p.lead_in = 2.0;
        p.lead_out = 2.0;
        p.tabs = 3;
        p.tab_width = 2.0;
        p.tab_height = 0.8;
        let tp = profile(&shape, &p).unwrap();
        // the hole's loop (22 mm round, three tabs) has 1.8 mm before its first tab: no
        // room for a ramp, so it is plunged, and said so
        let d = descents(&tp);
        assert!(d.plunges == 0 || !tp.warnings.is_empty(), "{side:?}: {d:?}");
        tp.walk(P3::default(), |from, m, to| {
            if let Move::Arc { center, .. } = m {
                let (r0, r1) = (from.xy().dist(*center), to.xy().dist(*center));
                assert!(
                    (r0 - r1).abs() < 1e-6,
                    "{side:?}: an arc from {from:?} to {to:?}"
                );
            }
        });
    }
}
