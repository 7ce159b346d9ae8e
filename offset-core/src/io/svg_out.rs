//! A small SVG writer of shapes: one colour per layer, +Y up, lines and exact arcs.

use crate::geom::{Bounds, Shape};
use std::fmt::Write;

/// Draws the layers (each a shape and a CSS colour) into one SVG document, the view box
/// fitted to all of them with a 5% margin and Y flipped so that +Y points up.
pub fn shapes_svg(layers: &[(&Shape, &str)]) -> String {
    let mut b = Bounds::EMPTY;
    for (s, _) in layers {
        b = b.union(&s.bounds());
    }
    if b.is_empty() {
        b.add_point(crate::geom::Point::new(0.0, 0.0));
        b.add_point(crate::geom::Point::new(1.0, 1.0));
    }
    let size = b.width().max(b.height()).max(1e-9);
    let m = size * 0.05;
    let stroke = size / 500.0;
    let mut out = String::new();
    let _ = writeln!(
        out,
        r#"<svg xmlns="http://www.w3.org/2000/svg" viewBox="{} {} {} {}">"#,
        b.min.x - m,
        -(b.max.y + m),
        b.width() + 2.0 * m,
        b.height() + 2.0 * m
    );
    for (shape, colour) in layers {
        let _ = writeln!(
            out,
            r#"<g fill="none" stroke="{colour}" stroke-width="{stroke}" transform="scale(1,-1)">"#
        );
        for p in &shape.paths {
            if p.is_empty() {
                continue;
            }
            let mut d = String::new();
            let v0 = p.vertices[0];
            let _ = write!(d, "M{} {}", v0.x, v0.y);
            for i in 0..p.segment_count() {
                let a = p.vertices[i];
                let e = p.vertices[(i + 1) % p.len()];
                if a.bulge == 0.0 {
                    let _ = write!(d, " L{} {}", e.x, e.y);
                } else {
                    let chord = a.pos().dist(e.pos());
                    let r = chord * (1.0 + a.bulge * a.bulge) / (4.0 * a.bulge.abs());
                    let large = u8::from(a.bulge.abs() > 1.0);
                    // in the drawing's own (y-up) frame a counter-clockwise arc has sweep 1
                    let sweep = u8::from(a.bulge > 0.0);
                    let _ = write!(d, " A{r} {r} 0 {large} {sweep} {} {}", e.x, e.y);
                }
            }
            if p.closed {
                d.push_str(" Z");
            }
            let _ = writeln!(out, r#"<path d="{d}"/>"#);
        }
        out.push_str("</g>\n");
    }
    out.push_str("</svg>\n");
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::{Point, Polyline};

    #[test]
    fn draws_each_layer_with_its_colour_and_arcs() {
        let a = Shape::new(vec![Polyline::circle(Point::new(0.0, 0.0), 5.0)]);
        let b = Shape::new(vec![Polyline::rect(
            Point::new(-6.0, -6.0),
            Point::new(6.0, 6.0),
        )]);
        let svg = shapes_svg(&[(&a, "grey"), (&b, "red")]);
        assert!(svg.contains(r#"stroke="grey""#) && svg.contains(r#"stroke="red""#));
        assert_eq!(svg.matches(" A5 5 0 0 1 ").count(), 2, "{svg}");
        assert!(svg.contains("viewBox=\"-6.6 -6.6 13.2 13.2\""), "{svg}");
    }
}
