//! Shared helpers of the offset tests: shape generators, the independent area from
//! Clipper2, and the distance checker's verdict.
#![allow(dead_code)]

/// Independent checks of solid meshes (testkit/README.md).
pub use machlink_testkit::mesh_check;

use offset_core::check::{check_offset, first_crossing, Report};
use offset_core::geom::{Point, Polyline, Region, Vertex};
use offset_core::offset::seg::Seg;

/// Clipper2 at 1e-5 mm resolution.
#[derive(Debug, Default, Copy, Clone, PartialEq, Hash)]
pub struct Fine;
impl clipper2::PointScaler for Fine {
    const MULTIPLIER: f64 = 1e5;
}

/// Points of a closed polyline, arcs flattened to chords whose sagitta stays below `sag`.
pub fn flatten(p: &Polyline, sag: f64) -> Vec<(f64, f64)> {
    let mut pts = Vec::new();
    for i in 0..p.segment_count() {
        let a = p.vertices[i];
        let b = p.vertices[(i + 1) % p.len()];
        let s = Seg::from_bulge(a.pos(), b.pos(), a.bulge);
        let k = if s.is_arc() {
            // sagitta of a chord spanning angle φ: r (1 - cos φ/2)
            let phi = 2.0 * (1.0 - (sag / s.r).min(1.0)).acos();
            ((s.sw.abs() / phi.max(1e-6)).ceil() as usize).clamp(1, 100_000)
        } else {
            1
        };
        for j in 0..k {
            let q = s.point_at(j as f64 / k as f64);
            pts.push((q.x, q.y));
        }
    }
    pts
}

fn ccw(mut poly: Vec<(f64, f64)>) -> Vec<(f64, f64)> {
    let mut a = 0.0;
    for i in 0..poly.len() {
        let (x0, y0) = poly[i];
        let (x1, y1) = poly[(i + 1) % poly.len()];
        a += x0 * y1 - x1 * y0;
    }
    if a < 0.0 {
        poly.reverse();
    }
    poly
}

/// Points along an arc (or a line) from t = 0 to 1, chords within `sag` of the curve.
fn arc_points(s: &Seg, r: f64, sag: f64) -> Vec<Point> {
    let k = if s.is_arc() && r > 0.0 {
        ((s.sw.abs() * (r / (8.0 * sag)).sqrt()).ceil() as usize).clamp(1, 200_000)
    } else {
        1
    };
    let sa = s.start_angle();
    (0..=k)
        .map(|j| {
            let ang = sa + s.sw * j as f64 / k as f64;
            s.c + Point::new(ang.cos(), ang.sin()) * r
        })
        .collect()
}

/// The band of points within d of the closed boundaries, as polygons: a rectangle per
/// line, an annular sector per arc (its inner radius clamped at the centre), and a
/// 1440-gon disk at every vertex.
fn band(boundaries: &[Polyline], d: f64) -> Vec<Vec<(f64, f64)>> {
    let mut out = Vec::new();
    let disk = 1440;
    for pl in boundaries {
        for i in 0..pl.segment_count() {
            let va = pl.vertices[i];
            let vb = pl.vertices[(i + 1) % pl.len()];
            let s = Seg::from_bulge(va.pos(), vb.pos(), va.bulge);
            let poly: Vec<Point> = if s.is_arc() {
                let mut o = arc_points(&s, s.r + d, 1e-6);
                let inner = (s.r - d).max(0.0);
                if inner == 0.0 {
                    o.push(s.c);
                } else {
                    let mut q = arc_points(&s, inner, 1e-6);
                    q.reverse();
                    o.extend(q);
                }
                o
            } else {
                let nn = (s.b - s.a).unit().perp() * d;
                vec![s.a + nn, s.b + nn, s.b - nn, s.a - nn]
            };
            out.push(ccw(poly.iter().map(|q| (q.x, q.y)).collect()));
            out.push(
                (0..disk)
                    .map(|j| {
                        let ang = j as f64 / disk as f64 * std::f64::consts::TAU;
                        (va.x + d * ang.cos(), va.y + d * ang.sin())
                    })
                    .collect(),
            );
        }
    }
    out
}

/// The area of the region offset by `d`, computed by Clipper2 independently of the
/// kernel: the band of points within |d| of the boundaries (see `band`) united with the
/// region to grow it or cut from it to shrink it. Clipper2's own `inflate` spaces its round
/// joins at |d|/500, too coarse to compare areas at our tolerance.
pub fn clipper_area(boundaries: &[Polyline], d: f64) -> f64 {
    use clipper2::{FillRule, Paths};
    let flat: Vec<Vec<(f64, f64)>> = boundaries.iter().map(|b| flatten(b, 1e-6)).collect();
    let band: Paths<Fine> = band(boundaries, d.abs()).into();
    let region: Paths<Fine> = flat.into();
    let out = if d > 0.0 {
        region
            .to_clipper_subject()
            .add_clip(band)
            .union(FillRule::NonZero)
    } else {
        region
            .to_clipper_subject()
            .add_clip(band)
            .difference(FillRule::NonZero)
    };
    out.unwrap().signed_area()
}

pub fn total_area(ps: &[Polyline]) -> f64 {
    ps.iter().map(|p| p.area()).sum()
}

pub fn total_length(ps: &[Polyline]) -> f64 {
    ps.iter().map(|p| p.length()).sum()
}

pub fn region_paths(rs: &[Region]) -> Vec<Polyline> {
    rs.iter()
        .flat_map(|r| r.boundaries().cloned().collect::<Vec<_>>())
        .collect()
}

/// Asserts the offset property and that the result does not cross itself.
pub fn assert_offset(input: &[Polyline], output: &[Polyline], d: f64, tol: f64) -> Report {
    let r = check_offset(input, output, d, tol);
    assert!(
        r.within(tol),
        "offset by {d} deviates: {r:?}\ninput: {input:?}\noutput: {output:?}"
    );
    if let Some((path, at)) = first_crossing(output, tol) {
        panic!("output path {path} crosses itself at {at:?}\ninput: {input:?}\noutput: {output:?}");
    }
    r
}

/// Asserts our area agrees with Clipper2's within tolerance × perimeter (plus Clipper's
/// own arc approximation).
pub fn assert_area(input: &[Polyline], output: &[Polyline], d: f64, tol: f64) {
    let ours = total_area(output);
    let theirs = clipper_area(input, d);
    let slack = tol * total_length(output).max(total_length(input)) + 1e-9 * (1.0 + ours.abs());
    assert!(
        (ours - theirs).abs() <= slack,
        "area {ours} vs clipper {theirs} (slack {slack})\ninput: {input:?}\noutput: {output:?}"
    );
}

/// A star polygon (counter-clockwise) with radii from `radii`, evenly spread angles.
pub fn star(center: Point, radii: &[f64]) -> Polyline {
    let n = radii.len();
    let pts: Vec<Point> = radii
        .iter()
        .enumerate()
        .map(|(i, r)| {
            let a = i as f64 / n as f64 * std::f64::consts::TAU;
            center + Point::new(a.cos(), a.sin()) * *r
        })
        .collect();
    Polyline::from_points(&pts, true)
}

/// A star with some sides bulged (bulges small enough that the star stays simple).
pub fn star_with_arcs(center: Point, radii: &[f64], bulges: &[f64]) -> Polyline {
    let mut p = star(center, radii);
    for (v, b) in p.vertices.iter_mut().zip(bulges) {
        v.bulge = *b;
    }
    p
}

pub fn v(x: f64, y: f64, b: f64) -> Vertex {
    Vertex::new(x, y, b)
}

/// r = r0 + Σ a_k sin(f_k θ + φ_k), sampled at n points.
pub fn gear(n: usize, r0: f64, waves: &[(f64, f64, f64)]) -> Polyline {
    let pts: Vec<Point> = (0..n)
        .map(|i| {
            let a = std::f64::consts::TAU * i as f64 / n as f64;
            let r = r0
                + waves
                    .iter()
                    .map(|(amp, f, ph)| amp * (f * a + ph).sin())
                    .sum::<f64>();
            Point::new(r * a.cos(), r * a.sin())
        })
        .collect();
    Polyline::from_points(&pts, true)
}

/// Links at depth against every link at the safe height, on one input: the retracts, rapids
/// and machine time of both printed, and fewer retracts with links at depth asserted.
pub fn assert_fewer_retracts(
    name: &str,
    at_depth: &offset_core::toolpath::Toolpath,
    safe: &offset_core::toolpath::Toolpath,
) {
    use offset_core::cutsim::retracts;
    let (n_low, n_high) = (retracts(at_depth), retracts(safe));
    let k = offset_core::stats::Kinematics::default();
    let (s_low, s_high) = (at_depth.stats(&k), safe.stats(&k));
    eprintln!(
        "{name}: {n_high} retracts, rapids {:.0} mm, {:.1} s with every link at the safe height; {n_low} retracts, rapids {:.0} mm, {:.1} s with links at depth",
        s_high.rapid_length,
        s_high.time(),
        s_low.rapid_length,
        s_low.time()
    );
    assert!(
        n_low < n_high,
        "{name}: {n_low} retracts with links at depth, {n_high} without"
    );
}

/// Whether the move runs level at one of `heights` (a link at a lift height).
pub fn level_at_any(m: &offset_core::cutsim::MoveReport, heights: &[f64]) -> bool {
    heights
        .iter()
        .any(|z| (m.from.z - z).abs() < 1e-9 && (m.to.z - z).abs() < 1e-9)
}

/// The lift heights of links in a program of 1 mm levels down to `depth`: each level's Z,
/// and the stock top, plus the link lift.
pub fn lift_heights(depth: f64) -> Vec<f64> {
    (0..=(depth as usize))
        .map(|k| -(k as f64) + offset_core::ops::pocket::LINK_LIFT)
        .collect()
}

/// Links at depth remove the same material as links at the safe height, to 0.1 % of the
/// volume (a cell's column of a pass's rim), mm³.
pub fn assert_same_removal(name: &str, at_depth: f64, safe: f64) {
    assert!(
        (at_depth - safe).abs() <= 1e-3 * safe,
        "{name}: {at_depth:.1} mm³ removed with links at depth, {safe:.1} without"
    );
}
