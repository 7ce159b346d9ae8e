//! 3D previews: a mesh shaded in an isometric view with a 3D tool path drawn over it, as SVG.
//!
//! The view looks from the front-right-top corner (+X right and away, +Y left and away, +Z
//! up): screen right is (X + Y)/√2, screen up (−X + Y + 2Z)/√6. Faces are shaded by the
//! angle between their normal and a light over the viewer's left shoulder, painted far to
//! near; faces turned away are left out of a closed mesh. Moves use the 2D preview's
//! colours: cutting lines blue, arcs green, plunges purple, rapids red dashed; a ring marks
//! where the first cut starts and arrows the cut direction. Below the drawing: a scale bar
//! (one length along any axis: the view shows X, Y and Z at one scale), the X/Y/Z axes as
//! drawn, and a legend of what is drawn.

use crate::geom::{Point, Segment};
use crate::mesh::{Mesh, V3};
use crate::preview::{
    arrow_d, arrows_along, label_number, scale_length, PreviewOptions, ARC_COLOUR,
    DIRECTION_COLOUR, LINEAR_COLOUR, PLUNGE_COLOUR, RAPID_COLOUR, START_COLOUR, TEXT_COLOUR,
};
use crate::toolpath::{arc_segment, Move, Toolpath};
use std::fmt::Write;

/// The most faces a preview paints; a bigger mesh paints every k-th face of those facing
/// the viewer (a preview, not a render).
pub const MAX_PREVIEW_FACES: usize = 200_000;

const RIGHT: V3 = V3::new(
    std::f64::consts::FRAC_1_SQRT_2,
    std::f64::consts::FRAC_1_SQRT_2,
    0.0,
);

fn up() -> V3 {
    V3::new(-1.0, 1.0, 2.0) / 6f64.sqrt()
}

/// Towards the viewer.
fn toward() -> V3 {
    V3::new(1.0, -1.0, 1.0) / 3f64.sqrt()
}

/// Screen coordinates of a point (x right, y up) and its depth towards the viewer.
pub fn project(p: V3) -> (f64, f64, f64) {
    (p.dot(RIGHT), p.dot(up()), p.dot(toward()))
}

/// Draws a mesh and/or a 3D tool path in the isometric view, `width_px` wide, with the scale
/// bar, the axes and the legend.
pub fn svg(mesh: Option<&Mesh>, tp: Option<&Toolpath>, width_px: f64) -> String {
    svg_with(
        mesh,
        tp,
        &PreviewOptions {
            width_px,
            ..Default::default()
        },
    )
}

/// Draws a mesh and/or a 3D tool path in the isometric view: `o.scale_bar` draws the scale
/// bar and the axes, `o.legend` the legend (`o.swept` is for plan views only).
pub fn svg_with(mesh: Option<&Mesh>, tp: Option<&Toolpath>, o: &PreviewOptions) -> String {
    let width_px = o.width_px;
    let mut lo = (f64::INFINITY, f64::INFINITY);
    let mut hi = (f64::NEG_INFINITY, f64::NEG_INFINITY);
    let mut grow = |p: V3| {
        let (x, y, _) = project(p);
        lo = (lo.0.min(x), lo.1.min(y));
        hi = (hi.0.max(x), hi.1.max(y));
    };
    if let Some(m) = mesh {
        for f in &m.faces {
            for &v in f {
                grow(m.vertices[v as usize]);
            }
        }
    }
    let mut pts: Vec<(V3, V3, Move)> = Vec::new();
    if let Some(t) = tp {
        let start = t
            .moves
            .iter()
            .find_map(|m| match m {
                Move::Rapid { to } | Move::Linear { to, .. } | Move::Arc { to, .. } => Some(*to),
                _ => None,
            })
            .unwrap_or_default();
        t.walk(start, |from, m, to| {
            let (a, b) = (V3::from_p3(from), V3::from_p3(to));
            grow(a);
            grow(b);
            pts.push((a, b, m.clone()));
        });
    }
    if !lo.0.is_finite() {
        lo = (0.0, 0.0);
        hi = (1.0, 1.0);
    }
    let size = (hi.0 - lo.0).max(hi.1 - lo.1).max(1e-6);
    let margin = size * 0.04;
    // what the legend names, in the order it names them
    let same_xy = |a: V3, b: V3| (a.x - b.x).abs() < 1e-9 && (a.y - b.y).abs() < 1e-9;
    let has = |f: &dyn Fn(V3, V3, &Move) -> bool| pts.iter().any(|(a, b, m)| f(*a, *b, m));
    let mut legend: Vec<(&str, &str)> = Vec::new();
    if mesh.is_some() {
        legend.push(("part", "part"));
    }
    let cutting = |a: V3, b: V3, m: &Move| match m {
        Move::Linear { .. } => !same_xy(a, b) || b.z > a.z,
        Move::Arc { .. } => true,
        _ => false,
    };
    if has(&cutting) {
        legend.push(("start", "start"));
        legend.push(("direction", "cut direction"));
    }
    for (key, text, on) in [
        (
            "linear",
            "cut",
            has(&|a, b, m| matches!(m, Move::Linear { .. }) && !(same_xy(a, b) && b.z < a.z)),
        ),
        (
            "arc",
            "arc cut",
            has(&|_, _, m| matches!(m, Move::Arc { .. })),
        ),
        (
            "plunge",
            "straight down",
            has(&|a, b, m| matches!(m, Move::Linear { .. }) && same_xy(a, b) && b.z < a.z),
        ),
        (
            "rapid",
            "rapid",
            has(&|_, _, m| matches!(m, Move::Rapid { .. })),
        ),
    ] {
        if on {
            legend.push((key, text));
        }
    }
    let line = size / 28.0;
    // a row of two lines for the scale bar and the axes, then the legend three to a row
    if !o.legend {
        legend.clear();
    }
    let rows = legend.len().div_ceil(3) as f64;
    let band = match (o.scale_bar, rows > 0.0) {
        (true, _) => line * (2.9 + rows),
        (false, true) => line * (0.5 + rows),
        (false, false) => 0.0,
    };
    let (w, h) = (
        hi.0 - lo.0 + 2.0 * margin,
        hi.1 - lo.1 + 2.0 * margin + band,
    );
    let px_w = width_px.max(16.0);
    let px_h = (px_w * h / w).clamp(16.0, 20_000.0);
    let sw = size / 600.0;
    let mut out = String::new();
    let (x0, y_top) = (lo.0 - margin, hi.1 + margin);
    let _ = writeln!(
        out,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{px_w:.0}" height="{px_h:.0}" viewBox="{} {} {} {}">"#,
        n(x0),
        n(-y_top),
        n(w),
        n(h)
    );
    let _ = writeln!(
        out,
        r#"<rect x="{}" y="{}" width="{}" height="{}" fill="white"/>"#,
        n(x0),
        n(-y_top),
        n(w),
        n(h)
    );
    // screen y grows downwards: draw with y negated
    if let Some(m) = mesh {
        shade(&mut out, m, sw);
    }
    if tp.is_some() {
        out.push_str("<g fill=\"none\" stroke-linecap=\"round\">\n");
        let dash = format!("{} {}", n(sw * 6.0), n(sw * 4.0));
        for (a, b, m) in pts.iter().cloned() {
            let line = |out: &mut String, a: V3, b: V3, colour: &str, dashed: bool| {
                let (ax, ay, _) = project(a);
                let (bx, by, _) = project(b);
                let _ = writeln!(
                    out,
                    r#"<path d="M{} {}L{} {}" stroke="{colour}" stroke-width="{}"{}/>"#,
                    n(ax),
                    n(-ay),
                    n(bx),
                    n(-by),
                    n(sw * 1.5),
                    if dashed {
                        format!(r#" stroke-dasharray="{dash}""#)
                    } else {
                        String::new()
                    }
                );
            };
            let same_xy = (a.x - b.x).abs() < 1e-9 && (a.y - b.y).abs() < 1e-9;
            match &m {
                Move::Rapid { .. } => line(&mut out, a, b, RAPID_COLOUR, true),
                Move::Linear { .. } if same_xy && b.z < a.z => {
                    line(&mut out, a, b, PLUNGE_COLOUR, false)
                }
                Move::Linear { .. } => line(&mut out, a, b, LINEAR_COLOUR, false),
                Move::Arc { center, ccw, .. } => {
                    let seg = arc_segment(a.p3().xy(), b.p3().xy(), *center, *ccw);
                    let k = ((seg.length() / (size / 200.0)).ceil() as usize).clamp(2, 256);
                    let mut prev = a;
                    for i in 1..=k {
                        let t = i as f64 / k as f64;
                        let q = seg.point_at(t);
                        let p = V3::new(q.x, q.y, a.z + (b.z - a.z) * t);
                        line(&mut out, prev, p, ARC_COLOUR, false);
                        prev = p;
                    }
                }
                _ => {}
            }
        }
        out.push_str("</g>\n");
        draw_start_and_direction(&mut out, &pts, size, sw);
    }
    draw_band(
        &mut out,
        &legend,
        o.scale_bar,
        (lo.0, lo.1 - margin),
        w,
        line,
        sw,
    );
    out.push_str("</svg>\n");
    out
}

/// The ring where the first cut starts and arrows of the cut direction, on screen.
fn draw_start_and_direction(out: &mut String, pts: &[(V3, V3, Move)], size: f64, sw: f64) {
    let screen = |p: V3| {
        let (x, y, _) = project(p);
        Point::new(x, -y)
    };
    let mut start = None;
    let mut cuts = Vec::new();
    for (a, b, m) in pts {
        if !matches!(m, Move::Linear { .. } | Move::Arc { .. }) {
            continue;
        }
        start.get_or_insert(*a);
        match m {
            Move::Arc { center, ccw, .. } => {
                let seg = arc_segment(a.p3().xy(), b.p3().xy(), *center, *ccw);
                let k = ((seg.length() / (size / 200.0)).ceil() as usize).clamp(2, 256);
                let mut prev = *a;
                for i in 1..=k {
                    let t = i as f64 / k as f64;
                    let q = seg.point_at(t);
                    let p = V3::new(q.x, q.y, a.z + (b.z - a.z) * t);
                    cuts.push(Segment::Line {
                        a: screen(prev),
                        b: screen(p),
                    });
                    prev = p;
                }
            }
            _ => {
                let (sa, sb) = (screen(*a), screen(*b));
                if sa.dist(sb) > 1e-9 {
                    cuts.push(Segment::Line { a: sa, b: sb });
                }
            }
        }
    }
    for (p, d) in arrows_along(&cuts, size) {
        let _ = writeln!(
            out,
            r#"<path d="{}" fill="{DIRECTION_COLOUR}" stroke="none"/>"#,
            arrow_d(p, d, sw * 6.0)
        );
    }
    if let Some(s) = start {
        let p = screen(s);
        let _ = writeln!(
            out,
            r#"<circle cx="{}" cy="{}" r="{}" fill="{START_COLOUR}" stroke="{TEXT_COLOUR}" stroke-width="{}"/>"#,
            n(p.x),
            n(p.y),
            n(sw * 8.0),
            n(sw * 1.5)
        );
    }
}

/// Below the drawing (whose lower left, on screen with y up, is `corner`): the scale bar and
/// the axes, then the legend.
fn draw_band(
    out: &mut String,
    legend: &[(&str, &str)],
    scale: bool,
    corner: (f64, f64),
    w: f64,
    line: f64,
    sw: f64,
) {
    let left = corner.0;
    let mut row_y = -corner.1 + line * 0.9;
    if scale {
        row_y += line * 0.3;
        scale_and_axes(out, left, row_y, w, line, sw);
        row_y += line * 1.9;
    }
    let col = w / 3.0;
    for (k, (key, text)) in legend.iter().enumerate() {
        legend_entry(
            out,
            key,
            text,
            (left + col * (k % 3) as f64, row_y + line * (k / 3) as f64),
            line,
            sw,
        );
    }
}

/// The scale bar (one length along any axis) and the X/Y/Z axes as the view draws them, on
/// the band's row at `row_y`.
fn scale_and_axes(out: &mut String, left: f64, row_y: f64, w: f64, line: f64, sw: f64) {
    let font = line * 0.6;
    // one mm along X, Y or Z is this long on screen
    let per_mm = (2.0f64 / 3.0).sqrt();
    let len = scale_length(w * 0.2 / per_mm);
    let tick = line * 0.25;
    let _ = writeln!(
        out,
        r#"<path d="M{} {}V{}H{}V{}" fill="none" stroke="{TEXT_COLOUR}" stroke-width="{}"/>"#,
        n(left),
        n(row_y - tick),
        n(row_y),
        n(left + len * per_mm),
        n(row_y - tick),
        n(sw * 2.0)
    );
    let _ = writeln!(
        out,
        r#"<text x="{}" y="{}" font-family="sans-serif" font-size="{}" fill="{TEXT_COLOUR}">{} mm along X, Y or Z</text>"#,
        n(left + len * per_mm + line * 0.3),
        n(row_y),
        n(font),
        label_number(len)
    );
    // the axes as the view draws them, from one corner
    let origin = Point::new(left + w * 0.75, row_y - line * 0.4);
    for (axis, dir) in [
        ("X", V3::new(1.0, 0.0, 0.0)),
        ("Y", V3::new(0.0, 1.0, 0.0)),
        ("Z", V3::new(0.0, 0.0, 1.0)),
    ] {
        let (dx, dy, _) = project(dir);
        let d = Point::new(dx, -dy);
        let l = d.x.hypot(d.y);
        let d = Point::new(d.x / l, d.y / l);
        let tip = Point::new(origin.x + d.x * line * 1.3, origin.y + d.y * line * 1.3);
        let _ = writeln!(
            out,
            r#"<path d="M{} {}L{} {}" stroke="{TEXT_COLOUR}" stroke-width="{}"/><path d="{}" fill="{TEXT_COLOUR}"/>"#,
            n(origin.x),
            n(origin.y),
            n(tip.x),
            n(tip.y),
            n(sw * 2.0),
            arrow_d(tip, d, sw * 4.0)
        );
        let at = Point::new(
            origin.x + d.x * line * 1.8 - font * 0.3,
            origin.y + d.y * line * 1.8 + font * 0.35,
        );
        let _ = writeln!(
            out,
            r#"<text x="{}" y="{}" font-family="sans-serif" font-size="{}" fill="{TEXT_COLOUR}">{axis}</text>"#,
            n(at.x),
            n(at.y),
            n(font)
        );
    }
}

/// One swatch of the legend and its text, at `(x, y)` (the text's baseline).
fn legend_entry(out: &mut String, key: &str, text: &str, (x, y): (f64, f64), line: f64, sw: f64) {
    let font = line * 0.6;
    {
        let sample = line * 1.2;
        let ym = y - font * 0.35;
        let dash = format!("{} {}", n(sw * 6.0), n(sw * 4.0));
        let swatch = match key {
            "part" => format!(
                r##"<rect x="{}" y="{}" width="{}" height="{}" fill="#b0b0b0"/>"##,
                n(x),
                n(ym - font * 0.4),
                n(sample),
                n(font * 0.8)
            ),
            "start" => format!(
                r#"<circle cx="{}" cy="{}" r="{}" fill="{START_COLOUR}" stroke="{TEXT_COLOUR}" stroke-width="{}"/>"#,
                n(x + sample / 2.0),
                n(ym),
                n(sw * 8.0),
                n(sw * 1.5)
            ),
            "direction" => format!(
                r#"<path d="{}" fill="{DIRECTION_COLOUR}"/>"#,
                arrow_d(
                    Point::new(x + sample / 2.0, ym),
                    Point::new(1.0, 0.0),
                    sw * 6.0
                )
            ),
            other => {
                let (c, dashed) = match other {
                    "linear" => (LINEAR_COLOUR, false),
                    "arc" => (ARC_COLOUR, false),
                    "plunge" => (PLUNGE_COLOUR, false),
                    _ => (RAPID_COLOUR, true),
                };
                format!(
                    r#"<path d="M{} {}H{}" stroke="{c}" stroke-width="{}"{}/>"#,
                    n(x),
                    n(ym),
                    n(x + sample),
                    n(sw * 2.0),
                    if dashed {
                        format!(r#" stroke-dasharray="{dash}""#)
                    } else {
                        String::new()
                    }
                )
            }
        };
        out.push_str(&swatch);
        out.push('\n');
        let _ = writeln!(
            out,
            r#"<text x="{}" y="{}" font-family="sans-serif" font-size="{}" fill="{TEXT_COLOUR}">{text}</text>"#,
            n(x + sample + line * 0.3),
            n(y),
            n(font)
        );
    }
}

/// Paints the mesh's faces, far to near, grey by their angle to the light.
fn shade(out: &mut String, m: &Mesh, sw: f64) {
    let closed = m.report().closed;
    let light = V3::new(-0.3, -0.6, 1.0).unit();
    let view = toward();
    let mut faces: Vec<(f64, usize, f64)> = Vec::new();
    for f in 0..m.faces.len() {
        let nrm = m.face_normal(f);
        if nrm == V3::ZERO {
            continue;
        }
        let facing = nrm.dot(view);
        if closed && facing <= 0.0 {
            continue;
        }
        // an open surface shows whichever side faces the viewer
        let nrm = if facing < 0.0 { -nrm } else { nrm };
        let [a, b, c] = m.triangle(f);
        let depth = ((a + b + c) / 3.0).dot(view);
        let lit = 0.25 + 0.7 * nrm.dot(light).max(0.0);
        faces.push((depth, f, lit));
    }
    faces.sort_by(|a, b| a.0.total_cmp(&b.0));
    let every = faces.len().div_ceil(MAX_PREVIEW_FACES).max(1);
    let _ = writeln!(
        out,
        r#"<g stroke-width="{}" stroke-linejoin="round">"#,
        n(sw * 0.3)
    );
    for (_, f, lit) in faces.into_iter().step_by(every) {
        let g = (lit.clamp(0.0, 1.0) * 255.0).round() as u8;
        let [a, b, c] = m.triangle(f);
        let (pa, pb, pc) = (project(a), project(b), project(c));
        let _ = writeln!(
            out,
            r##"<polygon points="{},{} {},{} {},{}" fill="#{g:02x}{g:02x}{g:02x}" stroke="#{g:02x}{g:02x}{g:02x}"/>"##,
            n(pa.0),
            n(-pa.1),
            n(pb.0),
            n(-pb.1),
            n(pc.0),
            n(-pc.1)
        );
    }
    out.push_str("</g>\n");
}

/// A number for SVG: short, finite.
fn n(v: f64) -> String {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::shapes::cube_with_boss;
    use crate::mesh::{finish3d, Cutter, Finish3dParams};

    #[test]
    fn the_view_keeps_z_up_and_x_to_the_right() {
        let (x0, y0, _) = project(V3::ZERO);
        let (x1, _, _) = project(V3::new(1.0, 0.0, 0.0));
        let (_, yz, _) = project(V3::new(0.0, 0.0, 1.0));
        assert!(x1 > x0 && yz > y0);
        // the three axes at equal scale on screen
        let len = |p: V3| {
            let (x, y, _) = project(p);
            x.hypot(y)
        };
        let lx = len(V3::new(1.0, 0.0, 0.0));
        assert!((len(V3::new(0.0, 1.0, 0.0)) - lx).abs() < 1e-12);
        assert!((len(V3::new(0.0, 0.0, 1.0)) - lx).abs() < 1e-12);
    }

    #[test]
    fn a_shaded_part_with_its_finish_parses_as_svg() {
        let m = cube_with_boss(30.0, 6.0, 8.0, 24);
        let tp = finish3d(
            &m,
            &Finish3dParams {
                cutter: Cutter::ball(6.0),
                stepover: crate::ops::Stepover::Mm(3.0),
                tolerance: 0.05,
                ..Default::default()
            },
        )
        .unwrap();
        let s = svg(Some(&m), Some(&tp), 600.0);
        let tree = usvg::Tree::from_str(&s, &usvg::Options::default()).unwrap();
        assert!(tree.root().abs_bounding_box().width() > 0.0);
        // a closed part shows only faces turned to the viewer: fewer than all
        let polys = s.matches("<polygon").count();
        assert!(
            polys > 0 && polys < m.faces.len(),
            "{polys} of {}",
            m.faces.len()
        );
        assert!(s.contains(LINEAR_COLOUR) && s.contains(RAPID_COLOUR));
        // a machinist's reading aids: the legend, a scale, the axes, the start and direction
        for label in [
            ">part<",
            ">start<",
            ">cut direction<",
            ">cut<",
            ">rapid<",
            ">X<",
            ">Y<",
            ">Z<",
        ] {
            assert!(s.contains(label), "no {label} in the 3D preview");
        }
        assert!(s.contains(" mm along X, Y or Z</text>") && s.contains(START_COLOUR));
        // the band lies inside the viewBox: every text's baseline above its bottom edge
        let vb = crate::preview::tests::view_box(&s);
        for y in s.split("<text x=\"").skip(1).map(|t| {
            t.split("y=\"")
                .nth(1)
                .unwrap()
                .split('"')
                .next()
                .unwrap()
                .parse::<f64>()
                .unwrap()
        }) {
            assert!(y > vb[1] && y < vb[1] + vb[3], "text at y {y} off {vb:?}");
        }
    }
}
