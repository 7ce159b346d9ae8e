//! Sewing benchmarks: stitch planning speed, and pattern upload through the simulated machine
//! on a pty with and without line noise. Run: `cargo bench -p machlink-sim --bench sewing_bench`.

use machlink_protocols::sewing::link::{SewingLink, SewingTiming};
use machlink_protocols::sewing::{StitchKind, StitchRecord};
use machlink_sim::sewing::{spawn_on_pty, SewingSimConfig};
use offset_core::geom::{Point, Polyline, Shape};
use offset_core::stitch::{stitch, StitchParams};
use std::time::{Duration, Instant};

/// 40 pockets with a rounded bottom (two arcs) and a circle label each.
fn shape() -> Shape {
    let mut paths = vec![];
    for k in 0..40 {
        let (ox, oy) = ((k % 8) as f64 * 150.0, (k / 8) as f64 * 170.0);
        let mut pocket = Polyline::from_points(
            &[
                Point::new(ox, oy + 40.0),
                Point::new(ox + 60.0, oy),
                Point::new(ox + 120.0, oy + 40.0),
                Point::new(ox + 120.0, oy + 150.0),
                Point::new(ox, oy + 150.0),
            ],
            true,
        );
        pocket.vertices[0].bulge = 0.2;
        pocket.vertices[1].bulge = 0.2;
        paths.push(pocket);
        paths.push(Polyline::circle(Point::new(ox + 60.0, oy + 90.0), 25.0));
    }
    Shape::new(paths)
}

fn planning() {
    let shape = shape();
    let p = StitchParams {
        rows: vec![0.0, -3.0],
        tie: true,
        ..Default::default()
    };
    let t = Instant::now();
    let tp = stitch(&shape, &p).expect("plans");
    let plan = t.elapsed();
    let drops = tp
        .moves
        .iter()
        .filter(|m| matches!(m, offset_core::Move::Stitch { .. }))
        .count();
    // anchor: the same rows' curves cut into ceil(len / L) equal pieces per segment, no
    // corners, no tolerance, no grid (what the planner does at the least)
    let rows: Vec<Polyline> = shape
        .paths
        .iter()
        .flat_map(|pl| {
            let mut v = vec![pl.clone()];
            v.extend(
                offset_core::offset::offset_polyline(
                    pl,
                    -3.0,
                    &offset_core::offset::OffsetOptions {
                        join: offset_core::offset::Join::Miter,
                        miter_limit: 10.0,
                        tolerance: 0.01,
                    },
                )
                .unwrap(),
            );
            v
        })
        .collect();
    let t = Instant::now();
    let mut n = 0usize;
    let mut acc = 0.0;
    for r in &rows {
        for s in r.segments() {
            let k = (s.length() / 2.5).ceil().max(1.0) as usize;
            for i in 1..=k {
                let q = s.point_at(i as f64 / k as f64);
                acc += q.x;
                n += 1;
            }
        }
    }
    let anchor = t.elapsed();
    std::hint::black_box(acc);
    println!(
        "| stitch planning, 80 curves × rows 0,-3, L 2.5 mm, ties | {:.1} ms | {drops} needle drops | {:.0} drops/ms |",
        plan.as_secs_f64() * 1e3,
        drops as f64 / (plan.as_secs_f64() * 1e3)
    );
    println!(
        "| anchor: the same curves cut into equal pieces (offsets made beforehand) | {:.1} ms | {n} points | {:.0} points/ms |",
        anchor.as_secs_f64() * 1e3,
        n as f64 / (anchor.as_secs_f64() * 1e3)
    );
}

fn upload(rt: &tokio::runtime::Runtime, records: &[StitchRecord], noise: f64) {
    rt.block_on(async {
        let sim = spawn_on_pty(SewingSimConfig {
            noise,
            seed: 11,
            ..Default::default()
        })
        .expect("sim");
        let mut link = SewingLink::open(
            &sim.path,
            115_200,
            SewingTiming {
                reply_timeout: Duration::from_millis(50),
                ..Default::default()
            },
        )
        .expect("link");
        let t = Instant::now();
        link.upload(records).await.expect("upload");
        let e = t.elapsed();
        let bytes = records.len() * StitchRecord::WIRE_LEN;
        let tr = sim.trace.lock().unwrap();
        println!(
            "| upload {} records ({} KiB), noise {:.1} % per byte each way | {:.2} s | {:.0} records/s | {} retransmissions, {} NAKs, {} repeats |",
            records.len(),
            bytes / 1024,
            noise * 100.0,
            e.as_secs_f64(),
            records.len() as f64 / e.as_secs_f64(),
            link.retransmissions,
            tr.corrupt_frames,
            tr.duplicates
        );
        sim.task.abort();
    });
}

fn main() {
    println!("| what | time | size | rate |\n|---|---|---|---|");
    planning();
    let records: Vec<StitchRecord> = (0..20_000)
        .map(|i| {
            // a serpentine of 0.5 mm stitches, 1 mm between rows, inside the sewing area
            let (row, col) = (i / 200, i % 200);
            let x = if row % 2 == 0 { col * 5 } else { 995 - col * 5 };
            StitchRecord::new(StitchKind::Stitch, x, row * 10)
        })
        .collect();
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime");
    println!("\n| what | time | rate | faults |\n|---|---|---|---|");
    for noise in [0.0, 0.0005, 0.002] {
        upload(&rt, &records, noise);
    }
}
