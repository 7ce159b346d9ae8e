//! Feed that follows the load, on the 120 × 80 plate with two islands: simulated again, every
//! level cut's chip is within 10 % of the chip the programmed feed makes at the nominal
//! step-over (or the cut runs at the largest feed, which cannot reach it), no feed passes
//! the largest, the pocket still clears everything without a gouge, and the machine time
//! before and after is reported.

use offset_core::cutsim::feed::{self, chip_factor, FeedControl, FeedControlledPocket};
use offset_core::cutsim::{simulate, MoveKind, Part, SimOptions, Stock};
use offset_core::geom::{Point, Polyline, Shape};
use offset_core::ops::{Cutting, PocketParams, Stepover};
use offset_core::stats::Kinematics;
use offset_core::toolpath::{Move, Tool};

fn plate() -> Shape {
    Shape::new(vec![
        Polyline::rect(Point::new(0.0, 0.0), Point::new(120.0, 80.0)),
        Polyline::circle(Point::new(40.0, 40.0), 10.0),
        Polyline::rect(Point::new(75.0, 25.0), Point::new(95.0, 55.0)),
    ])
}

#[test]
fn on_the_plate_every_cut_keeps_the_chip_within_10_percent_and_no_feed_passes_the_largest() {
    let shape = plate();
    let max_feed = 2000.0;
    let p = FeedControlledPocket {
        pocket: PocketParams {
            cut: Cutting {
                tool: Tool::flat(6.0),
                depth: 2.0,
                stepdown: 1.0,
                feed: 800.0,
                ..Cutting::default()
            },
            stepover: Stepover::Percent(40.0),
        },
        feed_control: FeedControl {
            max_feed,
            cell: 0.1,
            ..FeedControl::default()
        },
    };
    let tp = feed::pocket(&shape, &p).unwrap();
    let plain = offset_core::ops::pocket(&shape, &p.pocket).unwrap();
    // the same simulation model, run again on the new path
    let stock = Stock::block(Point::new(0.0, 0.0), Point::new(120.0, 80.0), 0.0);
    let o = SimOptions {
        cell: 0.1,
        part: Some(Part {
            clear: shape.regions(),
            floor: -2.0,
        }),
        ..SimOptions::new(Tool::flat(6.0))
    };
    let rep = simulate(&tp, &stock, &o).unwrap();
    assert_eq!(rep.gouges, 0, "gouge at {:?}", rep.first_gouge);
    assert_eq!(rep.left, 0, "material left at {:?}", rep.first_left);
    let nominal = feed::stepover_engagement(2.4, 6.0);
    let target = 800.0 * chip_factor(nominal);
    let (mut on_target, mut at_max) = (0, 0);
    for m in rep.moves.iter().filter(|m| m.kind == MoveKind::Cut) {
        assert!(
            m.feed <= max_feed,
            "move {} runs at {} mm/min",
            m.index,
            m.feed
        );
        let chip = m.feed * chip_factor(m.engagement) / target;
        if (chip - 1.0).abs() <= 0.1 {
            on_target += 1;
        } else {
            assert!(
                m.feed == max_feed && chip < 1.0,
                "move {} ({:?} → {:?}) at {} mm/min and {:.1}° makes a chip {:.3} of the target",
                m.index,
                m.from,
                m.to,
                m.feed,
                m.engagement,
                chip
            );
            at_max += 1;
        }
    }
    assert!(
        on_target > 100,
        "{on_target} cuts on target, {at_max} at the largest feed"
    );
    for m in &tp.moves {
        if let Move::Linear { feed, .. } | Move::Arc { feed, .. } = m {
            assert!(*feed <= max_feed + 1e-9, "feed {feed}");
        }
    }
    let k = Kinematics {
        max_feed,
        ..Kinematics::default()
    };
    let (before, after) = (plain.stats(&k).time(), tp.stats(&k).time());
    eprintln!(
        "plate: {before:.1} s at 800 mm/min, {after:.1} s following the load; {on_target} cuts on target, {at_max} at {max_feed} mm/min"
    );
    assert!(after < before, "{after} s after, {before} s before");
    match &tp.moves[0] {
        Move::Comment { text } => assert!(text.starts_with("feed control: estimated"), "{text}"),
        other => panic!("no comment first: {other:?}"),
    }
}
