//! Offset kernel benchmark: machlink against cavalier_contours and Clipper2 on the same
//! inputs (wavy gears whose teeth self-intersect at the offset distance, with and without
//! islands, a dense circle offset to near-collapse, 20 pocket passes). Prints a markdown
//! table: time, output vertices and arcs, and the worst deviation the checker finds.
//!
//! Run: `cargo bench -p offset-core --bench offset_bench` (add `-- quick` to skip 1M rows).

use cavalier_contours::polyline::{PlineCreation, PlineSource, PlineSourceMut, Polyline as CPline};
use cavalier_contours::shape_algorithms::{Shape as CShape, ShapeOffsetOptions};
use offset_core::check::Checker;
use offset_core::geom::{Point, Polyline, Region, Vertex};
use offset_core::offset::{offset_region, OffsetOptions};
use std::time::{Duration, Instant};

#[derive(Debug, Default, Copy, Clone, PartialEq, Hash)]
struct Fine;
impl clipper2::PointScaler for Fine {
    const MULTIPLIER: f64 = 1e5;
}

fn gear(n: usize) -> Polyline {
    let teeth = 60.0;
    let pts: Vec<Point> = (0..n)
        .map(|i| {
            let a = i as f64 / n as f64 * std::f64::consts::TAU;
            let r = 50.0 + 2.0 * (teeth * a).sin();
            Point::new(r * a.cos(), r * a.sin())
        })
        .collect();
    Polyline::from_points(&pts, true)
}

fn islands() -> Vec<Polyline> {
    (0..10)
        .map(|k| {
            let a = k as f64 / 10.0 * std::f64::consts::TAU;
            Polyline::circle(Point::new(a.cos(), a.sin()) * 30.0, 4.0).reversed()
        })
        .collect()
}

fn dense_circle(n: usize) -> (Polyline, f64) {
    let r = 10.0;
    let pts: Vec<Point> = (0..n)
        .map(|i| {
            let a = i as f64 / n as f64 * std::f64::consts::TAU;
            Point::new(r * a.cos(), r * a.sin())
        })
        .collect();
    let inr = r * (std::f64::consts::PI / n as f64).cos();
    (Polyline::from_points(&pts, true), -(inr - 1e-3))
}

fn to_cav(p: &Polyline) -> CPline<f64> {
    let mut c = CPline::with_capacity(p.len(), p.closed);
    for v in &p.vertices {
        c.add(v.x, v.y, v.bulge);
    }
    c
}

fn from_cav(c: &CPline<f64>) -> Polyline {
    let vs = (0..c.vertex_count())
        .map(|i| {
            let v = c.at(i);
            Vertex::new(v.x, v.y, v.bulge)
        })
        .collect();
    Polyline::new(vs, c.is_closed())
}

fn flatten(p: &Polyline, tol: f64) -> Vec<(f64, f64)> {
    let mut out = Vec::new();
    for s in p.segments() {
        let k = match s {
            offset_core::Segment::Arc { radius, .. } => {
                let phi = 2.0 * (1.0 - (tol / radius).min(1.0)).acos();
                ((s.sweep().abs() / phi).ceil() as usize).max(1)
            }
            _ => 1,
        };
        for j in 0..k {
            let q = s.point_at(j as f64 / k as f64);
            out.push((q.x, q.y));
        }
    }
    out
}

struct Row {
    case: String,
    lib: &'static str,
    time: Duration,
    verts: usize,
    arcs: usize,
    dev: Option<f64>,
}

fn count(ps: &[Polyline]) -> (usize, usize) {
    let v = ps.iter().map(|p| p.len()).sum();
    let a = ps
        .iter()
        .map(|p| {
            (0..p.segment_count())
                .filter(|&i| p.vertices[i].bulge != 0.0)
                .count()
        })
        .sum();
    (v, a)
}

/// Best of `reps` runs.
fn time<T>(reps: usize, mut f: impl FnMut() -> T) -> (Duration, T) {
    let mut best = Duration::MAX;
    let mut out = None;
    for _ in 0..reps {
        let t = Instant::now();
        let r = f();
        best = best.min(t.elapsed());
        out = Some(r);
    }
    (best, out.expect("at least one run"))
}

fn deviation(input: &[Polyline], out: &[Polyline], d: f64, check: bool) -> Option<f64> {
    if !check {
        return None;
    }
    Some(Checker::new(input).check(out, d, 1e-3).worst())
}

/// One case through the three kernels; `passes` > 1 offsets each pass from the previous.
#[allow(clippy::too_many_arguments)]
fn case(
    rows: &mut Vec<Row>,
    name: &str,
    boundaries: Vec<Polyline>,
    d: f64,
    passes: usize,
    reps: usize,
    check: bool,
    clipper: bool,
) {
    let region = Region::new(boundaries[0].clone(), boundaries[1..].to_vec());
    let verts_in: usize = boundaries.iter().map(|p| p.len()).sum();
    let opts = OffsetOptions::default();
    // machlink
    let (t, (out, last_in)) = time(reps, || {
        let mut cur = vec![region.clone()];
        let mut prev = cur.clone();
        for _ in 0..passes {
            prev = cur.clone();
            cur = cur
                .iter()
                .flat_map(|r| offset_region(r, d, &opts).expect("valid input"))
                .collect();
        }
        (cur, prev)
    });
    let out: Vec<Polyline> = out.iter().flat_map(|r| r.boundaries().cloned()).collect();
    let last_in: Vec<Polyline> = last_in
        .iter()
        .flat_map(|r| r.boundaries().cloned())
        .collect();
    let (verts, arcs) = count(&out);
    eprintln!("{name}: machlink {t:?}");
    push(
        rows,
        Row {
            case: name.into(),
            lib: "machlink",
            time: t,
            verts,
            arcs,
            dev: deviation(&last_in, &out, d, check),
        },
    );
    // cavalier_contours: positive offsets go inward of counter-clockwise loops
    let shape = CShape::from_plines(region.boundaries().map(to_cav));
    let copts = ShapeOffsetOptions::default();
    let (t, (out, last_in)) = time(reps, || {
        let mut cur = shape.clone();
        let mut prev = cur.clone();
        for _ in 0..passes {
            prev = cur.clone();
            cur = cur.parallel_offset(-d, &copts);
        }
        (cur, prev)
    });
    let plines = |s: &CShape<f64>| -> Vec<Polyline> {
        s.ccw_plines
            .iter()
            .chain(s.cw_plines.iter())
            .map(|p| from_cav(&p.polyline))
            .collect()
    };
    let (out, last_in) = (plines(&out), plines(&last_in));
    let (verts, arcs) = count(&out);
    eprintln!("{name}: cavalier {t:?}");
    push(
        rows,
        Row {
            case: name.into(),
            lib: "cavalier_contours 0.9",
            time: t,
            verts,
            arcs,
            dev: deviation(&last_in, &out, d, check),
        },
    );
    if !clipper {
        return;
    }
    // Clipper2: polygons (arcs flattened to 1e-4), round joins at its default arc tolerance
    let flat: Vec<Vec<(f64, f64)>> = region.boundaries().map(|p| flatten(p, 1e-4)).collect();
    let paths: clipper2::Paths<Fine> = flat.into();
    let (t, (out, last_in)) = time(reps.min(if verts_in < 50_000 { 3 } else { 1 }), || {
        let mut cur = paths.clone();
        let mut prev = cur.clone();
        for _ in 0..passes {
            prev = cur.clone();
            cur = clipper2::inflate(
                cur.clone(),
                d,
                clipper2::JoinType::Round,
                clipper2::EndType::Polygon,
                2.0,
            );
        }
        (cur, prev)
    });
    let back = |ps: clipper2::Paths<Fine>| -> Vec<Polyline> {
        let v: Vec<Vec<(f64, f64)>> = ps.into();
        v.iter()
            .map(|p| {
                Polyline::from_points(
                    &p.iter().map(|&(x, y)| Point::new(x, y)).collect::<Vec<_>>(),
                    true,
                )
            })
            .collect()
    };
    let (out, last_in) = (back(out), back(last_in));
    let (verts, arcs) = count(&out);
    eprintln!("{name}: clipper {t:?}");
    push(
        rows,
        Row {
            case: name.into(),
            lib: "Clipper2 (clipper2 0.6)",
            time: t,
            verts,
            arcs,
            dev: deviation(&last_in, &out, d, check),
        },
    );
}

fn push(rows: &mut Vec<Row>, r: Row) {
    print(&r);
    rows.push(r);
}

fn print(r: &Row) {
    println!(
        "| {} | {} | {:.1} ms | {} | {} | {} |",
        r.case,
        r.lib,
        r.time.as_secs_f64() * 1e3,
        r.verts,
        r.arcs,
        r.dev
            .map_or("not checked".to_string(), |d| format!("{d:.2e}"))
    );
}

fn main() {
    println!("| case | kernel | time | output vertices | arcs | worst deviation (mm) |");
    println!("|---|---|---:|---:|---:|---:|");
    let quick = std::env::args().any(|a| a == "quick");
    let mut rows = Vec::new();
    let mut sizes = vec![1_000usize, 10_000, 100_000];
    if !quick {
        sizes.push(1_000_000);
    }
    for &n in &sizes {
        let reps = if n <= 10_000 {
            5
        } else if n <= 100_000 {
            3
        } else {
            1
        };
        let check = n <= 100_000;
        let clip = n < 1_000_000;
        let name = format!("gear {n}, d = -1");
        case(&mut rows, &name, vec![gear(n)], -1.0, 1, reps, check, clip);
        let mut b = vec![gear(n)];
        b.extend(islands());
        let name = format!("gear {n} + 10 islands, d = -1");
        case(&mut rows, &name, b, -1.0, 1, reps, check, clip);
    }
    let (c, d) = dense_circle(30_000);
    // Clipper2 did not finish this one within minutes: left out
    let name = "dense circle 30k, to 1e-3 of collapse";
    case(&mut rows, name, vec![c], d, 1, 3, false, false);
    let mut b = vec![gear(10_000)];
    b.extend(islands());
    let name = "20 pocket passes, gear 10k + islands, d = -1";
    case(&mut rows, name, b, -1.0, 20, 1, true, true);
}
