use offset_core::biarc::{fit_points, BiarcOptions};
use offset_core::geom::{Point, Segment};
fn main() {
    #[allow(non_snake_case)]
    let R: f64 = std::env::args()
        .nth(3)
        .map(|s| s.parse().unwrap())
        .unwrap_or(300.0);
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args[1].parse().unwrap();
    let tol: f64 = args[2].parse().unwrap();
    let pts: Vec<Point> = (0..n)
        .map(|i| {
            let a = std::f64::consts::TAU * i as f64 / n as f64;
            Point::new(R * a.cos(), R * a.sin())
        })
        .collect();
    let f = fit_points(
        &pts,
        true,
        &BiarcOptions {
            tolerance: tol,
            ..Default::default()
        },
    );
    for s in f.segments() {
        match s {
            Segment::Arc { center, radius, .. } => {
                println!("arc c {:?} r {} sweep {}", center, radius, s.sweep())
            }
            _ => println!("{:?}", s),
        }
    }
}
