//! The offset bench's input shapes, shared with `examples/kernel_case.rs` (which runs one
//! of them alone, for a profiler): issue 13's gear of `n` vertices (radius n/10, n/20 teeth
//! of amplitude 3), its ten round islands, and the dense circle of radius 10.
#![allow(dead_code)]

use offset_core::geom::{Point, Polyline};

pub fn gear(n: usize) -> Polyline {
    let (r0, teeth) = (n as f64 / 10.0, n as f64 / 20.0);
    let pts: Vec<Point> = (0..n)
        .map(|i| {
            let a = i as f64 / n as f64 * std::f64::consts::TAU;
            let r = r0 + 3.0 * (teeth * a).sin();
            Point::new(r * a.cos(), r * a.sin())
        })
        .collect();
    Polyline::from_points(&pts, true)
}

pub fn islands(n: usize) -> Vec<Polyline> {
    let r0 = n as f64 / 10.0;
    (0..10)
        .map(|k| {
            let a = k as f64 / 10.0 * std::f64::consts::TAU;
            Polyline::circle(Point::new(a.cos(), a.sin()) * (0.6 * r0), 0.08 * r0).reversed()
        })
        .collect()
}

pub fn gear_with_islands(n: usize) -> Vec<Polyline> {
    let mut b = vec![gear(n)];
    b.extend(islands(n));
    b
}

pub fn dense_circle(n: usize) -> Polyline {
    let pts: Vec<Point> = (0..n)
        .map(|i| {
            let a = i as f64 / n as f64 * std::f64::consts::TAU;
            Point::new(10.0 * a.cos(), 10.0 * a.sin())
        })
        .collect();
    Polyline::from_points(&pts, true)
}
