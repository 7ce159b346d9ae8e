use offset_core::geom::{Point, Polyline, Region};
use offset_core::offset::{first_crossing, offset_region, OffsetOptions};
fn gear(n: usize) -> Polyline {
    let pts: Vec<Point> = (0..n)
        .map(|i| {
            let a = std::f64::consts::TAU * i as f64 / n as f64;
            let r = 60.0 + 4.0 * (24.0 * a).sin() + 3.0 * (5.0 * a).sin();
            Point::new(r * a.cos(), r * a.sin())
        })
        .collect();
    Polyline::from_points(&pts, true)
}
fn main() {
    let n: usize = std::env::args().nth(1).unwrap().parse().unwrap();
    let d: f64 = std::env::args().nth(2).unwrap().parse().unwrap();
    let opts = OffsetOptions::default();
    let reg = Region::new(gear(n), vec![]);
    let mut cur = vec![reg];
    for step in 0..30 {
        let mut next = vec![];
        for r in &cur {
            match offset_region(r, -d, &opts) {
                Ok(v) => next.extend(v),
                Err(e) => {
                    println!("step {step}: {e}");
                    // find the seam issue
                    let pl = &r.outer;
                    let nv = pl.len();
                    for i in 0..nv {
                        let a = pl.vertices[i].pos();
                        let b = pl.vertices[(i + 1) % nv].pos();
                        let c = pl.vertices[(i + 2) % nv].pos();
                        let (u, v) = (b - a, c - b);
                        if u.dot(v) < 0.0 && (u.cross(v).abs() < 1e-6 * u.len() * v.len()) {
                            println!(
                                "back-step at {i}: {:?} {:?} {:?} lens {} {} bulges {} {}",
                                a,
                                b,
                                c,
                                u.len(),
                                v.len(),
                                pl.vertices[i].bulge,
                                pl.vertices[(i + 1) % nv].bulge
                            );
                        }
                    }
                    return;
                }
            }
        }
        if let Some(x) = first_crossing(
            &next
                .iter()
                .flat_map(|r| r.boundaries().cloned())
                .collect::<Vec<_>>(),
            1e-3,
        ) {
            println!("step {step}: output crosses {:?}", x);
        }
        cur = next;
        if cur.is_empty() {
            println!("done at step {step}");
            return;
        }
    }
    println!("30 steps ok");
}
