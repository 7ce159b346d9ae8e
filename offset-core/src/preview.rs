//! Preview drawings: shapes and tool paths as SVG, +Y up, moves coloured by type (rapids dashed), stitch points as dots.

use crate::geom::{Bounds, Point, Polyline, Segment, Shape};
use crate::toolpath::{arc_segment, Move, Toolpath, P3};
use std::f64::consts::PI;
use std::fmt::Write;

/// Colours of the preview, one per kind of move.
pub const SHAPE_COLOUR: &str = "#555555";
pub const RAPID_COLOUR: &str = "#d62728";
pub const LINEAR_COLOUR: &str = "#1f77b4";
pub const ARC_COLOUR: &str = "#2ca02c";
pub const PLUNGE_COLOUR: &str = "#9467bd";
pub const STITCH_COLOUR: &str = "#111111";
pub const JUMP_COLOUR: &str = "#ff7f0e";

/// Draws a shape and/or a tool path. The drawing is `width_px` wide, scaled to fit, with
/// the shape's outlines in grey, cutting lines blue, arcs green, plunges purple dots,
/// rapids red dashed, stitches black dots and jumps orange dashed.
pub fn svg(shape: Option<&Shape>, tp: Option<&Toolpath>, width_px: f64) -> String {
    let mut b = Bounds::EMPTY;
    if let Some(s) = shape {
        b = b.union(&s.bounds());
    }
    if let Some(t) = tp {
        t.walk(P3::default(), |from, m, to| {
            if !matches!(m, Move::Rapid { .. }) || from.z < 0.0 || to.z < 0.0 {
                b.add_point(to.xy());
                if let Move::Arc { center, ccw, .. } = m {
                    b = b.union(&arc_segment(from.xy(), to.xy(), *center, *ccw).bounds());
                }
            }
        });
    }
    if b.is_empty() {
        b.add_point(Point::default());
    }
    let size = b.width().max(b.height()).max(1e-6);
    let margin = size * 0.04;
    let (x0, y0) = (b.min.x - margin, b.min.y - margin);
    let (w, h) = (b.width() + 2.0 * margin, b.height() + 2.0 * margin);
    let px_w = width_px.max(16.0);
    let px_h = (px_w * h / w).clamp(16.0, 20_000.0);
    let sw = size / 500.0;
    let mut out = String::new();
    let _ = writeln!(
        out,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{px_w:.0}" height="{px_h:.0}" viewBox="{} {} {} {}">"#,
        f(x0),
        f(-(y0 + h)),
        f(w),
        f(h)
    );
    let _ = writeln!(
        out,
        r#"<rect x="{}" y="{}" width="{}" height="{}" fill="white"/>"#,
        f(x0),
        f(-(y0 + h)),
        f(w),
        f(h)
    );
    // +Y up: everything below is drawn in the shape's own coordinates
    out.push_str("<g transform=\"scale(1,-1)\" fill=\"none\" stroke-linecap=\"round\" stroke-linejoin=\"round\">\n");
    if let Some(s) = shape {
        for pl in &s.paths {
            let _ = writeln!(
                out,
                r#"<path d="{}" stroke="{SHAPE_COLOUR}" stroke-width="{}"/>"#,
                polyline_d(pl),
                f(sw * 2.0)
            );
        }
    }
    if let Some(t) = tp {
        draw_toolpath(&mut out, t, sw);
    }
    out.push_str("</g>\n</svg>\n");
    out
}

fn draw_toolpath(out: &mut String, t: &Toolpath, sw: f64) {
    let dash = format!("{} {}", f(sw * 6.0), f(sw * 4.0));
    t.walk(P3::default(), |from, m, to| {
        let (a, b) = (from.xy(), to.xy());
        let same_xy = a.dist(b) < 1e-9;
        match m {
            Move::Rapid { .. } if !same_xy => {
                let _ = writeln!(
                    out,
                    r#"<path d="M{} {}L{} {}" stroke="{RAPID_COLOUR}" stroke-width="{}" stroke-dasharray="{dash}"/>"#,
                    f(a.x), f(a.y), f(b.x), f(b.y), f(sw)
                );
            }
            Move::Linear { .. } if same_xy && to.z < from.z => {
                let _ = writeln!(
                    out,
                    r#"<circle cx="{}" cy="{}" r="{}" fill="{PLUNGE_COLOUR}"/>"#,
                    f(b.x),
                    f(b.y),
                    f(sw * 2.5)
                );
            }
            Move::Linear { .. } if same_xy => {}
            Move::Linear { .. } => {
                let _ = writeln!(
                    out,
                    r#"<path d="M{} {}L{} {}" stroke="{LINEAR_COLOUR}" stroke-width="{}"/>"#,
                    f(a.x), f(a.y), f(b.x), f(b.y), f(sw)
                );
            }
            Move::Arc { center, ccw, .. } => {
                let seg = arc_segment(a, b, *center, *ccw);
                let _ = writeln!(
                    out,
                    r#"<path d="M{} {}{}" stroke="{ARC_COLOUR}" stroke-width="{}"/>"#,
                    f(a.x), f(a.y), arc_d(&seg), f(sw)
                );
            }
            Move::Stitch { .. } => {
                let _ = writeln!(
                    out,
                    r#"<path d="M{} {}L{} {}" stroke="{STITCH_COLOUR}" stroke-width="{}"/><circle cx="{}" cy="{}" r="{}" fill="{STITCH_COLOUR}"/>"#,
                    f(a.x), f(a.y), f(b.x), f(b.y), f(sw * 0.6), f(b.x), f(b.y), f(sw * 2.0)
                );
            }
            Move::Jump { .. } if !same_xy => {
                let _ = writeln!(
                    out,
                    r#"<path d="M{} {}L{} {}" stroke="{JUMP_COLOUR}" stroke-width="{}" stroke-dasharray="{dash}"/>"#,
                    f(a.x), f(a.y), f(b.x), f(b.y), f(sw)
                );
            }
            _ => {}
        }
    });
}

/// A number for SVG: short, finite.
fn f(v: f64) -> String {
    if v.is_finite() {
        let s = format!("{v:.4}");
        let s = s.trim_end_matches('0').trim_end_matches('.');
        if s == "-0" {
            "0".into()
        } else {
            s.to_string()
        }
    } else {
        "0".into()
    }
}

/// The SVG arc command(s) from the segment's start to its end (split in two past a half turn).
fn arc_d(s: &Segment) -> String {
    let Segment::Arc { radius, ccw, .. } = *s else {
        let e = s.end();
        return format!("L{} {}", f(e.x), f(e.y));
    };
    let sweep = s.sweep();
    // in the flipped group the local frame is y-up, where sweep-flag 1 turns counter-clockwise
    let flag = if ccw { 1 } else { 0 };
    let mut d = String::new();
    let parts = if sweep.abs() > PI * 0.999 { 2 } else { 1 };
    for k in 1..=parts {
        let p = s.point_at(k as f64 / parts as f64);
        let _ = write!(
            d,
            "A{} {} 0 0 {flag} {} {}",
            f(radius),
            f(radius),
            f(p.x),
            f(p.y)
        );
    }
    d
}

/// The SVG path data of a polyline (bulge arcs as arcs).
pub fn polyline_d(pl: &Polyline) -> String {
    let mut d = String::new();
    if let Some(v) = pl.vertices.first() {
        let _ = write!(d, "M{} {}", f(v.x), f(v.y));
    }
    for s in pl.segments() {
        d.push_str(&arc_d(&s));
    }
    if pl.closed {
        d.push('Z');
    }
    d
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_drawing_parses_as_svg_and_flips_y() {
        let shape = Shape::new(vec![Polyline::circle(Point::new(10.0, 5.0), 4.0)]);
        let mut tp = Toolpath::new("t");
        tp.push(Move::Rapid {
            to: P3::new(14.0, 5.0, 5.0),
        });
        tp.push(Move::Linear {
            to: P3::new(14.0, 5.0, -1.0),
            feed: 100.0,
        });
        tp.push(Move::Arc {
            to: P3::new(6.0, 5.0, -1.0),
            center: Point::new(10.0, 5.0),
            ccw: true,
            feed: 100.0,
        });
        let s = svg(Some(&shape), Some(&tp), 400.0);
        // usvg reads it back; the arc ccw from (14,5) to (6,5) passes over the top (y = 9)
        let tree = usvg::Tree::from_str(&s, &usvg::Options::default()).unwrap();
        let bb = tree.root().abs_bounding_box();
        assert!(bb.width() > 0.0);
        assert!(s.contains(ARC_COLOUR) && s.contains(PLUNGE_COLOUR));
        // the ccw arc is drawn with sweep flag 1 in the y-up group
        assert!(s.contains("A4 4 0 0 1 10 9"), "{s}");
    }
}
