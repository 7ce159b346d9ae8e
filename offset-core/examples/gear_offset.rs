//! Offsets the benchmark's wavy gear (n vertices, optionally with 10 islands) `reps` times,
//! for profiling: `cargo run --release -p offset-core --example gear_offset -- 100000 20 [islands]`.
//! `circle` offsets n points on a circle to 1e-3 of collapse instead; `check` runs the
//! checker on the result.

use offset_core::geom::{Point, Polyline, Region};
use offset_core::offset::{offset_region, OffsetOptions};
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(100_000);
    let reps: usize = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(10);
    let with_islands = args.iter().any(|a| a == "islands");
    let check = args.iter().any(|a| a == "check");
    let pts: Vec<Point> = (0..n)
        .map(|i| {
            let a = i as f64 / n as f64 * std::f64::consts::TAU;
            let r = 50.0 + 2.0 * (60.0 * a).sin();
            Point::new(r * a.cos(), r * a.sin())
        })
        .collect();
    let islands = if with_islands {
        (0..10)
            .map(|k| {
                let a = k as f64 / 10.0 * std::f64::consts::TAU;
                Polyline::circle(Point::new(a.cos(), a.sin()) * 30.0, 4.0).reversed()
            })
            .collect()
    } else {
        Vec::new()
    };
    // `circle`: n points on a circle of radius 10 offset to 1e-3 of its inradius instead
    let circle = args.iter().any(|a| a == "circle");
    let (pts, d) = if circle {
        let pts = (0..n)
            .map(|i| {
                let a = i as f64 / n as f64 * std::f64::consts::TAU;
                Point::new(10.0 * a.cos(), 10.0 * a.sin())
            })
            .collect();
        let inr = 10.0 * (std::f64::consts::PI / n as f64).cos();
        (pts, -(inr - 1e-3))
    } else {
        (pts, -1.0)
    };
    let region = Region {
        outer: Polyline::from_points(&pts, true),
        islands,
    };
    let opts = OffsetOptions::default();
    let mut best = f64::INFINITY;
    let mut out = Vec::new();
    for _ in 0..reps {
        let t = Instant::now();
        out = offset_region(&region, d, &opts).expect("offset");
        best = best.min(t.elapsed().as_secs_f64());
    }
    let paths: Vec<Polyline> = out.iter().flat_map(|r| r.boundaries().cloned()).collect();
    let verts: usize = paths.iter().map(|p| p.len()).sum();
    println!(
        "n = {n}: best {:.1} ms, {} loops, {verts} output vertices",
        best * 1e3,
        paths.len()
    );
    if check {
        let input: Vec<Polyline> = region.boundaries().cloned().collect();
        let worst = offset_core::check::Checker::new(&input)
            .check(&paths, d, opts.tolerance)
            .worst();
        println!("worst deviation {worst:.2e}");
    }
}
