use offset_core::geom::{Point, Polyline, Shape};
use offset_core::ops::{pocket, Cutting, PocketParams, Stepover};
use offset_core::toolpath::Tool;
fn main() {
    let shape = Shape::new(vec![
        Polyline::rect(Point::new(0.0, 0.0), Point::new(60.0, 40.0)),
        Polyline::circle(Point::new(30.0, 20.0), 8.0),
    ]);
    let tp = pocket(
        &shape,
        &PocketParams {
            cut: Cutting {
                tool: Tool::flat(6.0),
                depth: 2.0,
                ..Default::default()
            },
            stepover: Stepover::Percent(40.0),
        },
    )
    .unwrap();
    std::fs::write(
        "/tmp/prev.svg",
        offset_core::preview::svg(Some(&shape), Some(&tp), 800.0),
    )
    .unwrap();
}
