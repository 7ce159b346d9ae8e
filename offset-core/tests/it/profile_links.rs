//! Links at depth in profiles: a loop with lead arcs goes back the way it came between its
//! depth passes instead of up to the safe height; it retracts fewer times than with every
//! link at the safe height (both counts printed), and the simulation shows the links
//! moving through air only (no material removed), no gouge in the part, no rapid through
//! material.

use crate::common::{assert_same_removal, level_at_any, lift_heights};
use offset_core::cutsim::{simulate, MoveKind, Part, SimOptions, Stock};
use offset_core::geom::{Point, Polyline, Region, Shape};
use offset_core::ops::{profile, profile_safe_links, Cutting, Entry, ProfileParams, Side};
use offset_core::toolpath::Tool;

fn check(name: &str, side: Side, entry: Entry, lead_in: f64, lead_out: f64) {
    let outline = Polyline::rect(Point::new(0.0, 0.0), Point::new(40.0, 30.0));
    let hole = Polyline::circle(Point::new(20.0, 15.0), 6.0);
    let shape = Shape::new(vec![outline.clone(), hole.clone()]);
    let depth = 3.0;
    let p = ProfileParams {
        side,
        cut: Cutting {
            tool: Tool::flat(3.0),
            depth,
            stepdown: 1.0,
            entry,
            ..Cutting::default()
        },
        lead_in,
        lead_out,
        ..ProfileParams::default()
    };
    let low = profile(&shape, &p).unwrap();
    let high = profile_safe_links(&shape, &p).unwrap();
    crate::common::assert_fewer_retracts(name, &low, &high);
    // the part: the plate with its hole; what may be cut lies round it (outside profile)
    // or in the hole (inside)
    let m = 10.0;
    let stock_box = Polyline::rect(Point::new(-m, -m), Point::new(40.0 + m, 30.0 + m));
    let clear = match side {
        Side::Outside => vec![
            Region::new(stock_box, vec![outline.reversed()]),
            Region::new(hole.clone(), vec![]),
        ],
        _ => Shape::new(vec![outline.clone(), hole.clone()]).regions(),
    };
    let o = SimOptions {
        cell: 0.05,
        part: Some(Part {
            clear,
            floor: -depth,
        }),
        ..SimOptions::new(p.cut.tool)
    };
    let stock = Stock::block(Point::new(-m, -m), Point::new(40.0 + m, 30.0 + m), 0.0);
    let rep = simulate(&low, &stock, &o).unwrap();
    let rep_high = simulate(&high, &stock, &o).unwrap();
    assert_eq!(rep.gouges, 0, "{name}: gouge at {:?}", rep.first_gouge);
    assert_eq!(rep.rapid_cuts, 0, "{name}: a rapid through material");
    assert_same_removal(name, rep.removed, rep_high.removed);
    // a link: a feed move that rises while moving across, or runs level at a lift height
    // (a pass's depth, or the stock top, plus the lift)
    let lifts = lift_heights(depth);
    let mut links = 0;
    for mv in &rep.moves {
        let level_lift = level_at_any(mv, &lifts);
        let rising = mv.to.z > mv.from.z + 1e-9;
        if mv.kind == MoveKind::Cut
            && mv.from.xy().dist(mv.to.xy()) > 1e-9
            && (level_lift || rising)
        {
            links += 1;
            assert!(
                mv.removed == 0.0 && mv.gouges == 0,
                "{name}: the link {:?} → {:?} cuts {} mm³",
                mv.from,
                mv.to,
                mv.removed
            );
        }
    }
    eprintln!("{name}: {links} link moves, none removing material");
    assert!(links > 0, "{name}: no link at depth");
}

#[test]
fn an_outside_profile_with_leads_links_back_through_its_own_slot() {
    check(
        "outside, leads 2/2, ramps",
        Side::Outside,
        Entry::Helix,
        2.0,
        2.0,
    );
}

#[test]
fn an_inside_profile_with_a_long_lead_in_links_back_through_its_own_slot() {
    check(
        "inside, leads 4/0, ramps",
        Side::Inside,
        Entry::Helix,
        4.0,
        0.0,
    );
}

#[test]
fn a_lead_out_only_and_plunge_entries_link_back_too() {
    check(
        "outside, leads 0/2, ramps",
        Side::Outside,
        Entry::Helix,
        0.0,
        2.0,
    );
    check(
        "outside, leads 2/2, plunges",
        Side::Outside,
        Entry::Plunge,
        2.0,
        2.0,
    );
}
