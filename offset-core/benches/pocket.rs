//! Pocketing benchmarks. Run: `cargo bench -p offset-core --bench pocket`
//!
//! 1. The 10 000-vertex wavy region with 10 islands at a 40 % step-over, planned with the
//!    offset kernel and with Clipper2's offsets under the same pass logic.
//! 2. Issue 13's gears (r = 60 + 4 sin 24θ + 3 sin 5θ; 10 000 vertices with 3 islands,
//!    100 000 without) pocketed with a 3 mm tool at 40 % as `plan` does it: geometry JSON
//!    read (and fitted with arcs), pocket, final fitting pass; beside the kernel's own time
//!    for the same passes (measured inside the pocket), and the same shapes pocketed as
//!    points (not fitted on import).
//! 3. Moves before and after fitting for sample shapes, and the fitter's own speed.

#[path = "../tests/it/pocket_support/mod.rs"]
mod pocket_support;

use offset_core::biarc::{fit_points, fit_toolpath, BiarcOptions};
use offset_core::geom::{Point, Polyline, Region, Shape};
use offset_core::io::{read_shape_with, ReadOptions};
use offset_core::offset::{offset_region, OffsetOptions};
use offset_core::ops::pocket::RegionOffset;
use offset_core::ops::{
    pocket_with, profile, Cutting, PocketParams, ProfileParams, Side, Stepover,
};
use offset_core::stats::Kinematics;
use offset_core::toolpath::{Tool, Toolpath};

#[global_allocator]
static HEAP: offset_core::heap::PlanningHeap = offset_core::heap::PlanningHeap;
use std::cell::Cell;
use std::f64::consts::TAU;
use std::time::Instant;

fn wavy() -> Shape {
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

/// Issue 13's gear, r = 60 + 4 sin 24θ + 3 sin 5θ, at `n` points; with 3 islands of radius
/// 8 on a circle of radius 28 when asked.
fn gear(n: usize, islands: bool) -> Shape {
    let pts: Vec<Point> = (0..n)
        .map(|i| {
            let a = TAU * i as f64 / n as f64;
            let r = 60.0 + 4.0 * (24.0 * a).sin() + 3.0 * (5.0 * a).sin();
            Point::new(r * a.cos(), r * a.sin())
        })
        .collect();
    let mut paths = vec![Polyline::from_points(&pts, true)];
    if islands {
        for k in 0..3 {
            let a = TAU * k as f64 / 3.0;
            paths.push(Polyline::circle(Point::new(a.cos(), a.sin()) * 28.0, 8.0));
        }
    }
    Shape::new(paths)
}

/// The shape as geometry JSON, as a CAD export or a script would hand it over.
fn json(shape: &Shape) -> Vec<u8> {
    offset_core::io::json::write(shape).into_bytes()
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

fn main() {
    offset_core::heap::hold_freed_memory();
    kernel_against_clipper();
    gears();
    moves_before_and_after_fitting();
}

fn kernel_against_clipper() {
    let shape = wavy();
    let p = PocketParams {
        stepover: Stepover::Percent(40.0),
        cut: Cutting {
            tool: Tool::flat(6.0),
            depth: 1.0,
            stepdown: 1.0,
            tolerance: 1e-3,
            ..PocketParams::default().cut
        },
    };
    println!("## 1. 10 000-vertex region with 10 islands, 6 mm tool, 40 %\n");
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
                let ms = ms(t);
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

/// Best of `reps` runs of `f`, in ms, with the last result.
fn best<T>(reps: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let mut best = f64::INFINITY;
    let mut out = None;
    for _ in 0..reps {
        let t = Instant::now();
        let r = f();
        best = best.min(ms(t));
        out = Some(r);
    }
    (best, out.expect("at least one run"))
}

fn gears() {
    println!(
        "\n## 2. Issue 13's gears, 3 mm tool, 40 % step-over, 1 mm deep, tolerance 0.001 mm\n"
    );
    println!("| shape | import (ms) | pocket (ms) | of which the kernel's offsets (ms) | fitting pass (ms) | total (ms) | passes | moves planned | moves after the fitting pass |");
    println!("|---|---|---|---|---|---|---|---|---|");
    let p = PocketParams {
        stepover: Stepover::Percent(40.0),
        cut: Cutting {
            tool: Tool::flat(3.0),
            depth: 1.0,
            stepdown: 1.0,
            tolerance: 1e-3,
            ..Default::default()
        },
    };
    let opts = OffsetOptions {
        tolerance: 1e-3,
        ..Default::default()
    };
    let fit = BiarcOptions::with_tolerance(1e-3);
    for (name, shape, reps) in [
        ("10 000-vertex gear, 3 islands", gear(10_000, true), 5),
        ("100 000-vertex gear", gear(100_000, false), 3),
    ] {
        let bytes = json(&shape);
        for fitted in [true, false] {
            let spent = Cell::new(0.0f64);
            let calls = Cell::new(0usize);
            let kernel = |r: &Region, d: f64| {
                let t = Instant::now();
                let out = offset_region(r, d, &opts);
                spent.set(spent.get() + t.elapsed().as_secs_f64());
                calls.set(calls.get() + 1);
                out
            };
            let (t_import, shape) = best(reps, || {
                if fitted {
                    read_shape_with(&bytes, "gear.json", &ReadOptions::default())
                        .expect("reads")
                        .0
                } else {
                    offset_core::io::json::read(&bytes, "gear.json").expect("reads")
                }
            });
            // the best of the runs, and the kernel's share of that run
            let mut t_pocket = f64::INFINITY;
            let mut kernel_ms = 0.0;
            let mut tp = None;
            for _ in 0..reps {
                spent.set(0.0);
                calls.set(0);
                let t = Instant::now();
                let r = pocket_with(&shape, &p, &kernel);
                let e = ms(t);
                if e < t_pocket {
                    t_pocket = e;
                    kernel_ms = spent.get() * 1e3;
                }
                tp = Some(r);
            }
            let tp = tp.expect("at least one run");
            let label = if fitted {
                format!("{name}, read as `plan` reads it (fitted with arcs)")
            } else {
                format!("{name}, read as points (not fitted)")
            };
            let tp = match tp {
                Ok(tp) => tp,
                Err(e) => {
                    println!("| {label} | {t_import:.1} | – | – | – | – | – | {e} | |");
                    continue;
                }
            };
            let (t_fit, (fitted_tp, _)) = best(reps, || fit_toolpath(&tp, &fit));
            println!(
                "| {label} | {t_import:.1} | {t_pocket:.1} | {kernel_ms:.1} | {t_fit:.1} | {:.1} | {} | {} | {} |",
                t_import + t_pocket + t_fit,
                calls.get(),
                tp.moves.len(),
                fitted_tp.moves.len()
            );
        }
    }
}

fn figures(tp: &Toolpath) -> String {
    let s = tp.stats(&Kinematics::default());
    format!(
        "{} lines, {} arcs, {:.0} s",
        s.lines + s.rapids,
        s.arcs,
        s.time()
    )
}

fn moves_before_and_after_fitting() {
    println!(
        "\n## 3. Moves before and after fitting (tolerance 0.001 mm; moves ≈ program lines)\n"
    );
    println!("| sample | import | moves planned | after the fitting pass | planned: lines, arcs, est. time | fitted: lines, arcs, est. time |");
    println!("|---|---|---|---|---|---|");
    let circle = |n: usize| {
        let pts: Vec<Point> = (0..n)
            .map(|i| {
                let a = TAU * i as f64 / n as f64;
                Point::new(300.0 * a.cos(), 300.0 * a.sin())
            })
            .collect();
        Shape::new(vec![Polyline::from_points(&pts, true)])
    };
    let profile_100 = |s: &Shape| {
        profile(
            s,
            &ProfileParams {
                side: Side::Outside,
                cut: Cutting {
                    tool: Tool::flat(100.0),
                    ..Default::default()
                },
                ..Default::default()
            },
        )
        .expect("plans")
    };
    let pocket_3 = |s: &Shape| {
        offset_core::ops::pocket(
            s,
            &PocketParams {
                stepover: Stepover::Percent(40.0),
                cut: Cutting {
                    tool: Tool::flat(3.0),
                    ..Default::default()
                },
            },
        )
        .expect("plans")
    };
    let fit = BiarcOptions::with_tolerance(1e-3);
    type Op<'a> = &'a dyn Fn(&Shape) -> Toolpath;
    let samples: [(&str, Shape, Op); 3] = [
        (
            "circle r 300 as 7 200 points, profiled outside, 100 mm tool",
            circle(7200),
            &profile_100,
        ),
        (
            "10 000-vertex gear with 3 islands, pocketed, 3 mm tool",
            gear(10_000, true),
            &pocket_3,
        ),
        (
            "wavy region with 10 islands, pocketed, 3 mm tool",
            wavy(),
            &pocket_3,
        ),
    ];
    for (name, shape, op) in samples {
        for fitted in [false, true] {
            let s = if fitted {
                read_shape_with(&json(&shape), "s.json", &ReadOptions::default())
                    .expect("reads")
                    .0
            } else {
                shape.clone()
            };
            let tp = op(&s);
            let (f, _) = fit_toolpath(&tp, &fit);
            println!(
                "| {name} | {} | {} | {} | {} | {} |",
                if fitted { "fitted" } else { "as points" },
                tp.moves.len(),
                f.moves.len(),
                figures(&tp),
                figures(&f)
            );
        }
    }
    println!("\n| the fitter alone | points | segments out | time (ms) |");
    println!("|---|---|---|---|");
    for n in [10_000, 100_000, 1_000_000] {
        let g = gear(n, false);
        let pts: Vec<Point> = g.paths[0].vertices.iter().map(|v| v.pos()).collect();
        let (t, f) = best(3, || fit_points(&pts, true, &fit));
        println!("| gear | {n} | {} | {t:.1} |", f.segment_count());
        let c = circle(n);
        let pts: Vec<Point> = c.paths[0].vertices.iter().map(|v| v.pos()).collect();
        let (t, f) = best(3, || fit_points(&pts, true, &fit));
        println!("| circle r 300 | {n} | {} | {t:.1} |", f.segment_count());
    }
}
