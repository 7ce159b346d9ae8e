// throwaway: time a stage result offset again
use offset_core::geom::Region;
use offset_core::offset::{offset_regions_valid, OffsetOptions};
use std::time::Instant;
#[path = "../benches/support/inputs.rs"]
mod inputs;
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let d1: f64 = args[1].parse().unwrap();
    let d2: f64 = args[2].parse().unwrap();
    let reps: usize = args.get(3).map(|a| a.parse().unwrap()).unwrap_or(200);
    let region = Region {
        outer: inputs::gear(10000),
        islands: inputs::islands(10000),
    };
    let opts = OffsetOptions::default();
    let r = offset_regions_valid(&[region], d1, &opts).unwrap();
    let mut best = f64::MAX;
    let mut n = 0;
    for _ in 0..reps {
        let t = Instant::now();
        let s = r.offset(d2, &opts).unwrap();
        best = best.min(t.elapsed().as_secs_f64() * 1e3);
        n = s.regions()[0].outer.vertices.len();
    }
    println!(
        "{} -> {n} vertices, best {best:.3} ms",
        r.regions()[0].outer.vertices.len()
    );
}
