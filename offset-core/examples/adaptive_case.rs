//! Plans adaptive clearing of one test shape with a 6 mm tool and reports what the cutting
//! simulation reads (0.1 mm cells): the worst engagement of a level cut (helices apart),
//! the moves over the bound, left material and gouges. For working on the planner without
//! the test binary: `cargo run --release -p offset-core --example adaptive_case -- plate`
//! (shapes: `rect`, `plate`, `neck`, `tri`; then optionally the bound in degrees and the
//! planning cell in mm).

use offset_core::cutsim::{simulate, MoveKind, Part, SimOptions, Stock};
use offset_core::geom::{Point, Polyline, Shape};
use offset_core::ops::{adaptive, AdaptiveParams, Cutting};
use offset_core::toolpath::{Move, Tool};

fn shape(name: &str) -> Shape {
    let p = Point::new;
    match name {
        "rect" => Shape::new(vec![Polyline::rect(p(0.0, 0.0), p(40.0, 30.0))]),
        "plate" => Shape::new(vec![
            Polyline::rect(p(0.0, 0.0), p(120.0, 80.0)),
            Polyline::circle(p(40.0, 40.0), 10.0),
            Polyline::rect(p(75.0, 25.0), p(95.0, 55.0)),
        ]),
        "tri" => Shape::new(vec![Polyline::from_points(
            &[p(0.0, 0.0), p(50.0, 0.0), p(10.0, 30.0)],
            true,
        )]),
        "neck" => Shape::new(vec![Polyline::from_points(
            &[
                p(0.0, 0.0),
                p(30.0, 0.0),
                p(30.0, 11.8),
                p(50.0, 11.8),
                p(50.0, 0.0),
                p(80.0, 0.0),
                p(80.0, 30.0),
                p(50.0, 30.0),
                p(50.0, 18.2),
                p(30.0, 18.2),
                p(30.0, 30.0),
                p(0.0, 30.0),
            ],
            true,
        )]),
        other => panic!("no shape {other}: rect, plate, neck or tri"),
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let name = args.first().map_or("rect", String::as_str);
    let bound: f64 = args
        .get(1)
        .map_or(70.0, |s| s.parse().expect("a bound in degrees"));
    let cell: f64 = args
        .get(2)
        .map_or(0.0, |s| s.parse().expect("a planning cell in mm"));
    let shape = shape(name);
    let p = AdaptiveParams {
        cut: Cutting {
            tool: Tool::flat(6.0),
            depth: 1.0,
            stepdown: 1.0,
            feed: 800.0,
            ..Cutting::default()
        },
        engagement: bound,
        cell,
        ..AdaptiveParams::default()
    };
    let t0 = std::time::Instant::now();
    let tp = adaptive(&shape, &p).expect("a plan");
    println!(
        "planned in {:.2} s, {} moves, {} retracts to the safe height",
        t0.elapsed().as_secs_f64(),
        tp.moves.len(),
        offset_core::cutsim::retracts(&tp)
    );
    if let Move::Comment { text } = &tp.moves[0] {
        println!("{text}");
    }
    for w in &tp.warnings {
        println!("warning: {w}");
    }
    let b = shape.bounds();
    let stock = Stock::block(
        b.min - Point::new(1.0, 1.0),
        b.max + Point::new(1.0, 1.0),
        0.0,
    );
    let o = SimOptions {
        cell: 0.1,
        part: Some(Part {
            clear: shape.regions(),
            floor: -1.0,
        }),
        ..SimOptions::new(Tool::flat(6.0))
    };
    // the program run twice: the second run cuts nothing, so what it reads is the part and
    // the corners no round tool reaches
    let n = tp.moves.len();
    let mut twice = tp.clone();
    twice.moves.extend(tp.moves.iter().cloned());
    let rep2 = simulate(&twice, &stock, &o).expect("a simulation");
    let again = |i: usize| {
        rep2.moves
            .iter()
            .find(|m| m.index == i + n)
            .map_or(f64::NAN, |m| m.engagement)
    };
    let rep = simulate(&tp, &stock, &o).expect("a simulation");
    // the helices: arcs about one centre that start going down
    let mut over: Vec<_> = rep
        .moves
        .iter()
        .filter(|m| m.kind == MoveKind::Cut && m.engagement > bound && m.from.z <= -1.0 + 1e-6)
        .collect();
    over.sort_by(|a, b| b.engagement.total_cmp(&a.engagement));
    // going into a sharp corner of a wall: the corner's turn is the least any path reads
    let corners = offset_core::cutsim::sharp_corners(&shape.regions(), 3.0);
    let (into, away): (Vec<_>, Vec<_>) = over
        .iter()
        .partition(|m| offset_core::cutsim::going_into(&corners, m.to.xy()).is_some());
    println!(
        "{} of them going into the {} sharp corners (the most {:.1}°), {} elsewhere",
        into.len(),
        corners.len(),
        into.first()
            .map_or(0.0, |m: &&&offset_core::cutsim::MoveReport| m.engagement),
        away.len()
    );
    let over = away;
    println!(
        "left {} cells, gouges {}, {} level moves over {bound}°",
        rep.left,
        rep.gouges,
        over.len()
    );
    for m in over.iter().take(30) {
        println!(
            "  move {} {:.1}° (again {:.1}°, removed {:.4} mm³) ({:.2}, {:.2}) -> ({:.2}, {:.2})",
            m.index,
            m.engagement,
            again(m.index),
            m.removed,
            m.from.x,
            m.from.y,
            m.to.x,
            m.to.y
        );
    }
}
