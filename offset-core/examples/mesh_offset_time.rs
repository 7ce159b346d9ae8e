//! Times one mesh offset of the benchmark's 4,032-triangle solid (a quick check beside
//! `cargo bench --bench mesh3d`). Run: `cargo run --release -p offset-core --example mesh_offset_time`
use offset_core::mesh::offset::{offset, MeshOffsetOptions};
use offset_core::mesh::shapes::height_field_solid;
use std::time::Instant;
fn main() {
    let solid = height_field_solid((0.0, 60.0), (0.0, 40.0), 42, 42, 0.0, |x, y| {
        10.0 + 3.0 * (x / 7.0).sin() * (y / 5.0).cos()
    });
    for tol in [0.1, 0.01] {
        let mut best = f64::INFINITY;
        for _ in 0..20 {
            let t = Instant::now();
            let r = offset(&solid, 1.0, &MeshOffsetOptions { tolerance: tol }).unwrap();
            best = best.min(t.elapsed().as_secs_f64());
            std::hint::black_box(r);
        }
        println!("tolerance {tol}: best of 20 {:.1} ms", best * 1e3);
    }
}
