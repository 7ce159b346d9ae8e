//! Flattening: Bézier curves, elliptical arcs and B-splines/NURBS into bulge polylines within a tolerance (true circular arcs stay arcs).
//!
//! Every curve is flattened in bounded time: one that would need more than [`MAX_POINTS`]
//! points (a huge curve for the tolerance) or parameters beyond [`MAX_ANGLE`] is refused
//! with a [`FlattenError`] rather than approximated coarsely.

use crate::geom::{Point, Vertex};
use std::f64::consts::{PI, TAU};

/// The most points one curve may be flattened into.
pub const MAX_POINTS: usize = 200_000;

/// The most points the readers flatten the curves of one drawing into (a few thousand
/// curves of a few hundred points each, and 32 MB at most): a small file of huge curves
/// must not fill the memory.
pub const MAX_DRAWING_POINTS: usize = 2_000_000;

/// The largest angle or ellipse parameter taken, radians (a million radians still places a
/// point to within 2e-10 radians).
pub const MAX_ANGLE: f64 = 1e6;

/// The deepest recursive subdivision of one of the eight first pieces of a curve.
const MAX_DEPTH: u32 = 24;

/// Why a curve could not be flattened.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
pub enum FlattenError {
    #[error("would need more than {MAX_POINTS} points to stay within the tolerance of {tol}")]
    TooManyPoints { tol: f64 },
    #[error("has a parameter or angle of {0} radians, beyond ±{MAX_ANGLE}")]
    AngleOutOfRange(f64),
    #[error("leaves the range of numbers we can compute with")]
    NotFinite,
    #[error("has knots, weights or control points that do not make a curve")]
    NotACurve,
}

/// Samples `f` on `[t0, t1]` so that the chords stay within `tol` of the curve: each piece
/// is split while its midpoint or quarter points lie farther than 0.9 × `tol` from the chord.
/// Appends the points after `f(t0)`, ending with `f(t1)`. Refuses when `out` would grow
/// beyond [`MAX_POINTS`] (so one curve flattened span by span into one `out` shares the
/// budget), or when a piece finer than 2⁻²⁷ of `[t0, t1]` is still not flat.
pub fn adaptive(
    f: &dyn Fn(f64) -> Point,
    t0: f64,
    t1: f64,
    tol: f64,
    out: &mut Vec<Point>,
) -> Result<(), FlattenError> {
    let tol = if tol.is_finite() && tol > 0.0 {
        tol
    } else {
        1e-3
    };
    // a few initial pieces so that an S-shaped piece whose midpoint sits on its chord is split
    let n0 = 8;
    let mut prev = f(t0);
    for i in 1..=n0 {
        let a = t0 + (t1 - t0) * (i - 1) as f64 / n0 as f64;
        let b = t0 + (t1 - t0) * i as f64 / n0 as f64;
        let pb = f(b);
        piece(f, a, b, prev, pb, tol, 0, out)?;
        prev = pb;
    }
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn piece(
    f: &dyn Fn(f64) -> Point,
    a: f64,
    b: f64,
    pa: Point,
    pb: Point,
    tol: f64,
    depth: u32,
    out: &mut Vec<Point>,
) -> Result<(), FlattenError> {
    let m = 0.5 * (a + b);
    let pm = f(m);
    if !(pa.is_finite() && pb.is_finite() && pm.is_finite()) {
        return Err(FlattenError::NotFinite);
    }
    // checked at three points, so keep a margin for the curve between them
    let chord_dist = |p: Point| crate::geom::Segment::Line { a: pa, b: pb }.distance_to(p) / 0.9;
    // and the curve leaves and reaches the chord's ends heading along it: a piece that
    // starts or ends at a sharp turn (the tip of a Bézier's U-turn) may overshoot that end
    // between the checked points, where the distance to the chord is the distance to its end
    let chord = pb - pa;
    let h = (b - a) / 64.0;
    let heads_on = (f(a + h) - pa).dot(chord) >= 0.0 && (pb - f(b - h)).dot(chord) >= 0.0;
    let flat = heads_on
        && chord_dist(pm) <= tol
        && chord_dist(f(0.5 * (a + m))) <= tol
        && chord_dist(f(0.5 * (m + b))) <= tol;
    if flat {
        if out.len() >= MAX_POINTS {
            return Err(FlattenError::TooManyPoints { tol });
        }
        out.push(pb);
        Ok(())
    } else if depth >= MAX_DEPTH {
        // MAX_POINTS is reached long before an even subdivision gets this deep: the curve
        // crowds into a sliver of its parameter range (extreme weights, say)
        Err(FlattenError::TooManyPoints { tol })
    } else {
        piece(f, a, m, pa, pm, tol, depth + 1, out)?;
        piece(f, m, b, pm, pb, tol, depth + 1, out)
    }
}

/// A cubic Bézier as points within `tol`, starting with `p0` and ending with `p3`.
pub fn cubic(
    p0: Point,
    p1: Point,
    p2: Point,
    p3: Point,
    tol: f64,
) -> Result<Vec<Point>, FlattenError> {
    let f = |t: f64| {
        let u = 1.0 - t;
        p0 * (u * u * u) + p1 * (3.0 * u * u * t) + p2 * (3.0 * u * t * t) + p3 * (t * t * t)
    };
    let mut out = vec![p0];
    adaptive(&f, 0.0, 1.0, tol, &mut out)?;
    Ok(out)
}

/// A quadratic Bézier as points within `tol`, starting with `p0` and ending with `p2`.
pub fn quadratic(p0: Point, p1: Point, p2: Point, tol: f64) -> Result<Vec<Point>, FlattenError> {
    let f = |t: f64| {
        let u = 1.0 - t;
        p0 * (u * u) + p1 * (2.0 * u * t) + p2 * (t * t)
    };
    let mut out = vec![p0];
    adaptive(&f, 0.0, 1.0, tol, &mut out)?;
    Ok(out)
}

/// An elliptical arc (DXF ELLIPSE): `center`, the major axis vector `major` (centre to the end
/// of the major axis), the minor/major `ratio`, and the parameters from `t0` to `t1` (radians,
/// counter-clockwise, within ±[`MAX_ANGLE`]; `t1 <= t0` wraps, a sweep of more than a turn
/// is taken modulo a turn). A circular arc (ratio 1) comes back as bulge arcs of at most
/// 90°; any other as line vertices within `tol`. The last vertex is the arc's end, with
/// bulge 0.
pub fn elliptical_arc(
    center: Point,
    major: Point,
    ratio: f64,
    t0: f64,
    t1: f64,
    tol: f64,
) -> Result<Vec<Vertex>, FlattenError> {
    for t in [t0, t1] {
        if t.is_nan() || t.abs() > MAX_ANGLE {
            return Err(FlattenError::AngleOutOfRange(t));
        }
    }
    // the sweep in (0, 2π], counting a sweep a hair over a whole number of turns as a turn
    let d = t1 - t0;
    let sweep = if d > 0.0 && d <= TAU + 1e-12 {
        d
    } else {
        match d.rem_euclid(TAU) {
            r if r == 0.0 || (d > 0.0 && r <= 1e-12) => r + TAU,
            r => r,
        }
    };
    let t1 = t0 + sweep;
    let minor = major.perp() * ratio;
    let at = |t: f64| center + major * t.cos() + minor * t.sin();
    let v = if (ratio.abs() - 1.0).abs() < 1e-9 {
        // a circle: the parameter is the angle (mirrored when the ratio is -1)
        let sweep = (t1 - t0) * ratio.signum();
        let n = (sweep.abs() / (PI / 2.0) - 1e-9).ceil().max(1.0) as usize;
        let bulge = (sweep / n as f64 / 4.0).tan();
        let mut v: Vec<Vertex> = (0..n)
            .map(|i| {
                let p = at(t0 + (t1 - t0) * i as f64 / n as f64);
                Vertex::new(p.x, p.y, bulge)
            })
            .collect();
        v.push(Vertex::line(at(t1)));
        v
    } else {
        let mut pts = vec![at(t0)];
        adaptive(&at, t0, t1, tol, &mut pts)?;
        pts.into_iter().map(Vertex::line).collect()
    };
    if v.iter().all(|v| v.pos().is_finite() && v.bulge.is_finite()) {
        Ok(v)
    } else {
        Err(FlattenError::NotFinite)
    }
}

/// A NURBS curve (DXF SPLINE): `degree`, the knot vector (`control.len() + degree + 1`
/// knots), control points and weights (empty for a non-rational B-spline), as points within
/// `tol`. Refuses with [`FlattenError::NotACurve`] when the data do not make a curve (too
/// few knots or points, knots decreasing, weights not positive, points at infinity).
pub fn nurbs(
    degree: usize,
    knots: &[f64],
    control: &[Point],
    weights: &[f64],
    tol: f64,
) -> Result<Vec<Point>, FlattenError> {
    let n = control.len();
    if degree == 0 || n <= degree || knots.len() != n + degree + 1 {
        return Err(FlattenError::NotACurve);
    }
    if !weights.is_empty()
        && (weights.len() != n || weights.iter().any(|w| w.is_nan() || *w <= 0.0))
    {
        return Err(FlattenError::NotACurve);
    }
    if knots.windows(2).any(|w| w[1].is_nan() || w[1] < w[0])
        || !control.iter().all(|p| p.is_finite())
    {
        return Err(FlattenError::NotACurve);
    }
    let (lo, hi) = (knots[degree], knots[n]);
    if hi.is_nan() || hi <= lo {
        return Err(FlattenError::NotACurve);
    }
    let w = |i: usize| if weights.is_empty() { 1.0 } else { weights[i] };
    let eval = |t: f64| -> Point {
        let t = t.clamp(lo, hi);
        // the knot span k with knots[k] <= t < knots[k+1], within [degree, n-1]
        let k = degree + knots[degree + 1..n].partition_point(|&u| u <= t);
        // de Boor on homogeneous points (x·w, y·w, w)
        let mut d: Vec<(f64, f64, f64)> = (0..=degree)
            .map(|j| {
                let i = k - degree + j;
                (control[i].x * w(i), control[i].y * w(i), w(i))
            })
            .collect();
        for r in 1..=degree {
            for j in (r..=degree).rev() {
                let i = k - degree + j;
                let den = knots[i + degree + 1 - r] - knots[i];
                let a = if den > 0.0 { (t - knots[i]) / den } else { 0.0 };
                d[j] = (
                    (1.0 - a) * d[j - 1].0 + a * d[j].0,
                    (1.0 - a) * d[j - 1].1 + a * d[j].1,
                    (1.0 - a) * d[j - 1].2 + a * d[j].2,
                );
            }
        }
        let (x, y, ww) = d[degree];
        Point::new(x / ww, y / ww)
    };
    let mut out = vec![eval(lo)];
    // each non-empty knot span is flattened on its own (the curve is smooth within a span)
    for k in degree..n {
        if knots[k + 1] > knots[k] {
            match adaptive(&eval, knots[k], knots[k + 1], tol, &mut out) {
                Err(FlattenError::NotFinite) => return Err(FlattenError::NotACurve),
                r => r?,
            }
        }
    }
    if out.iter().all(|p| p.is_finite()) {
        Ok(out)
    } else {
        Err(FlattenError::NotACurve)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::Polyline;

    #[test]
    fn circular_ellipse_is_bulge_arcs_on_the_circle() {
        let v = elliptical_arc(
            Point::new(1.0, 2.0),
            Point::new(5.0, 0.0),
            1.0,
            0.0,
            2.0 * PI,
            0.01,
        )
        .unwrap();
        let pl = Polyline::new(v[..v.len() - 1].to_vec(), true);
        assert_eq!(pl.len(), 4);
        assert!((pl.area() - PI * 25.0).abs() < 1e-9);
    }
}
