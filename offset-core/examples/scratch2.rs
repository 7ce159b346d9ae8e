use offset_core::biarc::{fit_points, BiarcOptions};
use offset_core::geom::Point;
use std::time::Instant;
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args[1].parse().unwrap();
    let tol: f64 = args[2].parse().unwrap();
    let pts: Vec<Point> = (0..n)
        .map(|i| {
            let a = std::f64::consts::TAU * i as f64 / n as f64;
            let r = 60.0 + 4.0 * (24.0 * a).sin() + 3.0 * (5.0 * a).sin();
            Point::new(r * a.cos(), r * a.sin())
        })
        .collect();
    let t = Instant::now();
    let f = fit_points(
        &pts,
        true,
        &BiarcOptions {
            tolerance: tol,
            ..Default::default()
        },
    );
    println!(
        "gear n {n} tol {tol}: {} segs in {:.1} ms",
        f.segment_count(),
        t.elapsed().as_secs_f64() * 1e3
    );
    let pts: Vec<Point> = (0..n)
        .map(|i| {
            let a = std::f64::consts::TAU * i as f64 / n as f64;
            Point::new(300.0 * a.cos(), 300.0 * a.sin())
        })
        .collect();
    let t = Instant::now();
    let f = fit_points(
        &pts,
        true,
        &BiarcOptions {
            tolerance: tol,
            ..Default::default()
        },
    );
    println!(
        "circle n {n} tol {tol}: {} segs in {:.1} ms",
        f.segment_count(),
        t.elapsed().as_secs_f64() * 1e3
    );
    // open long wavy line
    let pts: Vec<Point> = (0..n)
        .map(|i| {
            let x = 1000.0 * i as f64 / n as f64;
            Point::new(x, 5.0 * (x / 30.0).sin())
        })
        .collect();
    let t = Instant::now();
    let f = fit_points(
        &pts,
        false,
        &BiarcOptions {
            tolerance: tol,
            ..Default::default()
        },
    );
    println!(
        "wave n {n} tol {tol}: {} segs in {:.1} ms",
        f.segment_count(),
        t.elapsed().as_secs_f64() * 1e3
    );
}
