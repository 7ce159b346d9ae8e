// throwaway: a single offset's vertices and arc midpoints, their distance from the input
use offset_core::geom::{Polyline, Region};
use offset_core::offset::{offset_regions_valid, OffsetOptions};
#[path = "../benches/support/inputs.rs"]
mod inputs;
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let d: f64 = args[1].parse().unwrap();
    let region = Region {
        outer: inputs::gear(10000),
        islands: inputs::islands(10000),
    };
    let inp: Vec<Polyline> = std::iter::once(region.outer.clone())
        .chain(region.islands.clone())
        .collect();
    let r = offset_regions_valid(&[region], d, &OffsetOptions::default()).unwrap();
    let mut worst: f64 = 0.0;
    let mut n = 0;
    for reg in r.regions() {
        for p in std::iter::once(&reg.outer).chain(reg.islands.iter()) {
            for (i, v) in p.vertices.iter().enumerate() {
                let w = &p.vertices[(i + 1) % p.vertices.len()];
                let pts = [
                    offset_core::geom::Point::new(v.x, v.y),
                    offset_core::geom::Point::new((v.x + w.x) / 2.0, (v.y + w.y) / 2.0),
                ];
                for q in &pts[..1] {
                    let dist = inp
                        .iter()
                        .map(|b| b.distance_to(*q))
                        .fold(f64::INFINITY, f64::min);
                    worst = worst.max((dist - d.abs()).abs());
                    n += 1;
                }
            }
        }
    }
    println!(
        "{} regions, {n} vertices, worst |dist - d| {worst:.3e}",
        r.regions().len()
    );
}
