use offset_core::geom::{Point, Polyline, Region, Shape};
use offset_core::offset::{offset_region, OffsetOptions};
use offset_core::ops::{pocket_with, Cutting, PocketParams, Stepover};
use offset_core::toolpath::Tool;
use std::cell::Cell;
use std::time::Instant;
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
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args[1].parse().unwrap();
    let isl = args.iter().any(|a| a == "islands");
    let mut paths = vec![gear(n)];
    if isl {
        for k in 0..3 {
            let a = std::f64::consts::TAU * k as f64 / 3.0;
            paths.push(Polyline::circle(Point::new(a.cos(), a.sin()) * 28.0, 8.0));
        }
    }
    let mut shape = Shape::new(paths);
    if args.iter().any(|a| a == "fit") {
        let t = Instant::now();
        shape = offset_core::biarc::fit_shape(
            &shape,
            &offset_core::biarc::BiarcOptions::with_tolerance(1e-3),
        )
        .0;
        println!(
            "fit {:.1} ms -> {} segs",
            t.elapsed().as_secs_f64() * 1e3,
            shape.paths.iter().map(|p| p.segment_count()).sum::<usize>()
        );
    }
    let p = PocketParams {
        stepover: Stepover::Percent(40.0),
        cut: Cutting {
            tool: Tool::flat(3.0),
            ..Default::default()
        },
    };
    let opts = OffsetOptions {
        tolerance: 1e-3,
        ..Default::default()
    };
    let spent = Cell::new(0.0);
    let calls = Cell::new(0);
    let off = |r: &Region, d: f64| {
        let t = Instant::now();
        let o = offset_region(r, d, &opts);
        spent.set(spent.get() + t.elapsed().as_secs_f64());
        calls.set(calls.get() + 1);
        o
    };
    let t = Instant::now();
    let res = pocket_with(&shape, &p, &off);
    let total = t.elapsed().as_secs_f64();
    match res {
        Ok(tp) => println!(
            "n {n} islands {isl}: {:.1} ms total, {:.1} ms offsetting in {} calls, {} moves",
            total * 1e3,
            spent.get() * 1e3,
            calls.get(),
            tp.moves.len()
        ),
        Err(e) => println!("n {n}: error {e} after {:.1} ms", total * 1e3),
    }
}
