//! The engagement along the path as an SVG drawing: the stock and the part's outlines, the tool centre's path coloured from blue (no engagement) through green and yellow to red (a slot, 180° and more), rapids dashed grey, and a colour bar.

use super::{MoveKind, Report, Stock};
use crate::geom::{Bounds, Region};
use crate::preview::polyline_d;
use std::fmt::Write;

/// The colour of an engagement in degrees, in 10° steps up to 180°.
pub fn colour(deg: f64) -> String {
    let t = (deg / 180.0).clamp(0.0, 1.0);
    let t = (t * 18.0).round() / 18.0;
    // blue → cyan → green → yellow → red
    let stops = [
        (0.0, (49.0, 54.0, 149.0)),
        (0.25, (69.0, 170.0, 209.0)),
        (0.5, (102.0, 189.0, 99.0)),
        (0.75, (253.0, 219.0, 80.0)),
        (1.0, (215.0, 25.0, 28.0)),
    ];
    let mut c = stops[0].1;
    for w in stops.windows(2) {
        let ((t0, c0), (t1, c1)) = (w[0], w[1]);
        if t >= t0 && t <= t1 {
            let u = (t - t0) / (t1 - t0);
            c = (
                c0.0 + (c1.0 - c0.0) * u,
                c0.1 + (c1.1 - c0.1) * u,
                c0.2 + (c1.2 - c0.2) * u,
            );
        }
    }
    format!("#{:02x}{:02x}{:02x}", c.0 as u8, c.1 as u8, c.2 as u8)
}

fn f(v: f64) -> String {
    let s = format!("{v:.4}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" {
        "0".into()
    } else {
        s.into()
    }
}

/// Draws the report's path over the stock and the part, `width_px` wide.
pub fn svg(report: &Report, stock: &Stock, part: Option<&[Region]>, width_px: f64) -> String {
    let mut b = Bounds::EMPTY;
    for r in &stock.outline {
        b = b.union(&r.bounds());
    }
    for s in &report.samples {
        if report.moves[s.report].kind != MoveKind::Rapid || s.at.z < stock.top {
            b.add_point(s.at.xy());
        }
    }
    if b.is_empty() {
        b.add_point(crate::geom::Point::default());
    }
    let size = b.width().max(b.height()).max(1e-6);
    let margin = size * 0.04;
    let bar = size / 12.0;
    let (x0, y0) = (b.min.x - margin, b.min.y - margin - bar);
    let (w, h) = (b.width() + 2.0 * margin, b.height() + 2.0 * margin + bar);
    let px_w = width_px.max(16.0);
    let px_h = (px_w * h / w).clamp(16.0, 20_000.0);
    let sw = size / 400.0;
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
    let _ = writeln!(out, r#"<g transform="scale(1,-1)">"#);
    for r in &stock.outline {
        for pl in r.boundaries() {
            let _ = writeln!(
                out,
                r##"<path d="{}" fill="#eeeeee" stroke="#999999" stroke-width="{}"/>"##,
                polyline_d(pl),
                f(sw)
            );
        }
    }
    for r in part.unwrap_or(&[]) {
        for pl in r.boundaries() {
            let _ = writeln!(
                out,
                r##"<path d="{}" fill="none" stroke="#555555" stroke-width="{}"/>"##,
                polyline_d(pl),
                f(sw * 1.5)
            );
        }
    }
    // runs of samples of one colour (cutting) or rapids
    let mut run: Vec<(f64, f64)> = Vec::new();
    let mut key: Option<String> = None;
    let flush = |out: &mut String, run: &mut Vec<(f64, f64)>, key: &Option<String>| {
        if run.len() >= 2 {
            let mut d = String::new();
            for (i, (x, y)) in run.iter().enumerate() {
                let _ = write!(d, "{}{} {}", if i == 0 { "M" } else { "L" }, f(*x), f(*y));
            }
            let style = match key.as_deref() {
                Some("rapid") => format!(
                    r##"stroke="#aaaaaa" stroke-dasharray="{} {}" stroke-width="{}""##,
                    f(sw * 4.0),
                    f(sw * 3.0),
                    f(sw)
                ),
                Some(c) => format!(r#"stroke="{c}" stroke-width="{}""#, f(sw * 2.0)),
                None => String::new(),
            };
            let _ = writeln!(
                out,
                r#"<path d="{d}" fill="none" {style} stroke-linecap="round"/>"#
            );
        }
        run.clear();
    };
    let mut last: Option<(f64, f64)> = None;
    for s in &report.samples {
        let k = if report.moves[s.report].kind == MoveKind::Rapid {
            "rapid".to_string()
        } else {
            colour(s.engagement)
        };
        if key.as_deref() != Some(&k) {
            flush(&mut out, &mut run, &key);
            run.extend(last);
            key = Some(k);
        }
        let p = (s.at.x, s.at.y);
        run.push(p);
        last = Some(p);
    }
    flush(&mut out, &mut run, &key);
    let _ = writeln!(out, "</g>");
    // the colour bar below the drawing: 0° to 180°
    let (bx, by, bw, bh) = (
        b.min.x,
        -(b.min.y - margin - bar * 0.2),
        b.width() * 0.6,
        bar * 0.3,
    );
    for k in 0..18 {
        let _ = writeln!(
            out,
            r#"<rect x="{}" y="{}" width="{}" height="{}" fill="{}"/>"#,
            f(bx + bw * k as f64 / 18.0),
            f(by),
            f(bw / 18.0 + sw * 0.1),
            f(bh),
            colour((k as f64 + 0.5) * 10.0)
        );
    }
    let fs = bar * 0.28;
    for (deg, x) in [(0, bx), (90, bx + bw / 2.0), (180, bx + bw)] {
        let _ = writeln!(
            out,
            r##"<text x="{}" y="{}" font-size="{}" font-family="sans-serif" text-anchor="middle" fill="#222222">{deg}°</text>"##,
            f(x),
            f(by + bh + fs * 1.1),
            f(fs)
        );
    }
    let _ = writeln!(
        out,
        r##"<text x="{}" y="{}" font-size="{}" font-family="sans-serif" fill="#222222">engagement</text>"##,
        f(bx + bw + fs),
        f(by + bh),
        f(fs)
    );
    out.push_str("</svg>\n");
    out
}
