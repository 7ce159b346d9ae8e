//! Pocketing benchmark: a 10 000-vertex region with 10 islands at a 40 % step-over, planned
//! with the offset kernel and with Clipper2's offsets under the same pass logic.
//! Run: `cargo bench -p offset-core --bench pocket`

#[path = "../tests/pocket_support/mod.rs"]
mod pocket_support;

use offset_core::geom::{Point, Polyline, Region, Shape};
use offset_core::offset::{offset_region, OffsetOptions};
use offset_core::ops::pocket::RegionOffset;
use offset_core::ops::{pocket_with, PocketParams, Stepover};
use offset_core::toolpath::Tool;
use std::cell::Cell;
use std::f64::consts::TAU;
use std::time::Instant;

fn shape() -> Shape {
    let n = 10_000;
    let outer: Vec<Point> = (0..n)
        .map(|i| {
            let a = TAU * i as f64 / n as f64;
            let r = 100.0 + 6.0 * (7.0 * a).sin() + 2.0 * (23.0 * a).cos();
            Point::new(r * a.cos(), r * a.sin())
        })
        .collect();
    let mut paths = vec![Polyline::from_points(&outer, true)];
    for k in 0..10 {
        let a = TAU * k as f64 / 10.0;
        let c = Point::new(55.0 * a.cos(), 55.0 * a.sin());
        paths.push(Polyline::circle(c, 5.0 + (k % 3) as f64 * 2.0));
    }
    Shape::new(paths)
}

fn main() {
    let shape = shape();
    let p = PocketParams {
        stepover: Stepover::Percent(40.0),
        cut: offset_core::ops::Cutting {
            tool: Tool::flat(6.0),
            depth: 1.0,
            stepdown: 1.0,
            tolerance: 1e-3,
            ..PocketParams::default().cut
        },
    };
    println!("| offsets | time (ms) | of which offsetting (ms) | moves | cut length (mm) | rapid length (mm) |");
    println!("|---|---|---|---|---|---|");
    let opts = OffsetOptions {
        tolerance: p.cut.tolerance,
        ..Default::default()
    };
    let spent = Cell::new(0.0f64);
    let kernel = |r: &Region, d: f64| {
        let t = Instant::now();
        let out = offset_region(r, d, &opts);
        spent.set(spent.get() + t.elapsed().as_secs_f64());
        out
    };
    let clipper = |r: &Region, d: f64| {
        let t = Instant::now();
        let out = pocket_support::clipper_offset(r, d, 1e-3);
        spent.set(spent.get() + t.elapsed().as_secs_f64());
        out
    };
    let runs: [(&str, &RegionOffset); 2] = [
        ("offset kernel", &kernel),
        (
            "Clipper2 0.6 (round joins, 1 µm grid, regrouped by nesting)",
            &clipper,
        ),
    ];
    for (name, off) in runs {
        spent.set(0.0);
        let t = Instant::now();
        match pocket_with(&shape, &p, off) {
            Ok(tp) => {
                let ms = t.elapsed().as_secs_f64() * 1e3;
                let (cut, rapid) = tp.lengths();
                println!(
                    "| {name} | {ms:.0} | {:.0} | {} | {cut:.1} | {rapid:.1} |",
                    spent.get() * 1e3,
                    tp.moves.len()
                );
            }
            Err(e) => println!("| {name} | – | – | – | {e} | |"),
        }
    }
}
