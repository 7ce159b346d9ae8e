//! One of the offset bench's inputs (issue 25's), offset `reps` times, for profiling under
//! callgrind or perf without the whole bench:
//! `cargo run --release -p offset-core --example kernel_case -- CASE D [reps]`, where CASE
//! is `gear:N` (the bench's gear of N vertices), `gear+:N` (with its 10 islands) or
//! `circle:N` (N points on a circle of radius 10), and D the signed distance (`inr-1e-3`
//! for the dense circle's inradius less 1e-3). `incremental:K` after the reps makes K
//! passes, each from the previous result; `cav` offsets with cavalier_contours instead
//! (the bench's anchor, its shape built outside the timing as there; callgrind it with
//! `--toggle-collect='cavalier_contours::shape_algorithms::Shape*::parallel_offset*'`);
//! `between` runs a cavalier_contours offset of the same region, untimed, before each of
//! machlink's rounds, as the bench interleaves them.
//! Prints the best time, the output's size and a digest of its every coordinate (the same
//! digest before and after a change: the same results, bit for bit). With `KC_EACH` set in
//! the environment it also prints each round's time and page faults on stderr (the first
//! rounds at a million vertices fault the heap in; the later ones should take none).

use cavalier_contours::polyline::{PlineCreation, PlineSource, PlineSourceMut, Polyline as CPline};
use cavalier_contours::shape_algorithms::{Shape as CShape, ShapeOffsetOptions};
use offset_core::geom::{Polyline, Region};
use offset_core::offset::{offset_regions_valid, OffsetOptions};
use std::time::Instant;

#[global_allocator]
static HEAP: offset_core::heap::PlanningHeap = offset_core::heap::PlanningHeap;

#[path = "../benches/support/inputs.rs"]
mod inputs;
use inputs::{dense_circle as circle, gear, islands};

/// A boundary as cavalier_contours' polyline.
fn to_cav(p: &Polyline) -> CPline<f64> {
    let mut c = CPline::with_capacity(p.len(), p.closed);
    for v in &p.vertices {
        c.add(v.x, v.y, v.bulge);
    }
    c
}

/// The page faults this process has taken so far (`KC_EACH`'s rounds; 0 where libc is not
/// a dependency).
fn faults() -> i64 {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: getrusage writes the zeroed struct it is handed
    unsafe {
        let mut u: libc::rusage = std::mem::zeroed();
        libc::getrusage(libc::RUSAGE_SELF, &mut u);
        u.ru_minflt
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    0
}

fn main() {
    offset_core::heap::hold_freed_memory();
    let args: Vec<String> = std::env::args().collect();
    let usage =
        "usage: kernel_case gear:N|gear+:N|circle:N D [reps] [incremental:K] [cav | between]";
    let Some((kind, n)) = args.get(1).and_then(|a| a.split_once(':')) else {
        eprintln!("{usage}");
        std::process::exit(2);
    };
    let Ok(n) = n.parse::<usize>() else {
        eprintln!("{usage}");
        std::process::exit(2);
    };
    let region = match kind {
        "gear" => Region {
            outer: gear(n),
            islands: Vec::new(),
        },
        "gear+" => Region {
            outer: gear(n),
            islands: islands(n),
        },
        "circle" => Region {
            outer: circle(n),
            islands: Vec::new(),
        },
        _ => {
            eprintln!("{usage}");
            std::process::exit(2);
        }
    };
    let d = match args.get(2).map(String::as_str) {
        Some("inr-1e-3") => -(10.0 * (std::f64::consts::PI / n as f64).cos() - 1e-3),
        Some(x) => match x.parse::<f64>() {
            Ok(d) => d,
            Err(_) => {
                eprintln!("{usage}");
                std::process::exit(2);
            }
        },
        None => -2.0,
    };
    let reps: usize = args.get(3).and_then(|a| a.parse().ok()).unwrap_or(1);
    let passes: usize = args
        .iter()
        .find_map(|a| a.strip_prefix("incremental:"))
        .and_then(|k| k.parse().ok())
        .unwrap_or(1);
    if args.iter().any(|a| a == "cav") {
        let shape = CShape::from_plines(region.boundaries().map(to_cav));
        let mut best = f64::INFINITY;
        let mut verts = 0;
        for _ in 0..reps {
            let t = Instant::now();
            let mut cur = shape.parallel_offset(-d, &ShapeOffsetOptions::default());
            for _ in 1..passes {
                cur = cur.parallel_offset(-d, &ShapeOffsetOptions::default());
            }
            best = best.min(t.elapsed().as_secs_f64());
            verts = cur
                .ccw_plines
                .iter()
                .chain(cur.cw_plines.iter())
                .map(|p| p.polyline.vertex_count())
                .sum();
        }
        println!(
            "cavalier_contours {kind}:{n} d = {d}: best {:.3} ms of {reps}, {verts} output vertices",
            best * 1e3
        );
        return;
    }
    let opts = OffsetOptions::default();
    let mut best = f64::INFINITY;
    let mut out = Vec::new();
    // `between`: a cavalier_contours offset of the same region before each round, untimed,
    // as the bench interleaves the kernels (its buffers take the caches and the heap)
    let between = args
        .iter()
        .any(|a| a == "between")
        .then(|| CShape::from_plines(region.boundaries().map(to_cav)));
    // KC_EACH set: every round's time on stderr (the first rounds fault the heap in)
    let each = std::env::var_os("KC_EACH").is_some();
    for _ in 0..reps {
        if let Some(shape) = &between {
            std::hint::black_box(shape.parallel_offset(-d, &ShapeOffsetOptions::default()));
        }
        let f0 = faults();
        let t = Instant::now();
        // the first pass from the given region (checked), each later one from the pass
        // before (the kernel's result: no crossing search of its input)
        let mut cur = match offset_regions_valid(std::slice::from_ref(&region), d, &opts) {
            Ok(o) => o,
            Err(e) => {
                eprintln!("offset failed: {e}");
                std::process::exit(1);
            }
        };
        for _ in 1..passes {
            cur = match cur.offset(d, &opts) {
                Ok(o) => o,
                Err(e) => {
                    eprintln!("offset failed: {e}");
                    std::process::exit(1);
                }
            };
        }
        best = best.min(t.elapsed().as_secs_f64());
        if each {
            eprintln!(
                "  {:.3} ms, {} faults",
                t.elapsed().as_secs_f64() * 1e3,
                faults() - f0
            );
        }
        out = cur.into_regions();
    }
    let verts: usize = out
        .iter()
        .flat_map(|r| r.boundaries())
        .map(|p| p.len())
        .sum();
    // every output coordinate and bulge, bit for bit (FNV-1a): a change meant to leave the
    // results as they were prints the same digest
    let mut digest: u64 = 0xcbf2_9ce4_8422_2325;
    for v in out
        .iter()
        .flat_map(|r| r.boundaries())
        .flat_map(|p| &p.vertices)
    {
        for x in [v.x, v.y, v.bulge] {
            for b in x.to_bits().to_le_bytes() {
                digest = (digest ^ u64::from(b)).wrapping_mul(0x100_0000_01b3);
            }
        }
    }
    println!(
        "{kind}:{n} d = {d}: best {:.3} ms of {reps}, {} regions, {verts} output vertices, digest {digest:016x}",
        best * 1e3,
        out.len()
    );
}
