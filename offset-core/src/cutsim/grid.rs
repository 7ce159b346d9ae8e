//! The material as a height map: a fine square raster over the stock whose cells hold the
//! height of the material's top (minus infinity where there is none), cut by the tool's
//! swept disc, and the raster questions the simulation asks of regions (inside, how far).

use crate::geom::{Point, Region, Segment};

/// A height map of `nx` × `ny` square cells of side `h` mm, the first cell's lower-left
/// corner at `origin`. Cell (i, j) stands for the point at its centre.
#[derive(Clone, Debug)]
pub struct Grid {
    pub origin: Point,
    pub h: f64,
    pub nx: usize,
    pub ny: usize,
    /// The material's top per cell (row-major, j * nx + i); `f32::NEG_INFINITY` is air.
    pub top: Vec<f32>,
}

impl Grid {
    pub fn new(origin: Point, h: f64, nx: usize, ny: usize) -> Grid {
        Grid {
            origin,
            h,
            nx,
            ny,
            top: vec![f32::NEG_INFINITY; nx * ny],
        }
    }

    /// The centre of cell (i, j).
    pub fn centre(&self, i: usize, j: usize) -> Point {
        Point::new(
            self.origin.x + (i as f64 + 0.5) * self.h,
            self.origin.y + (j as f64 + 0.5) * self.h,
        )
    }

    /// The cell holding `p`, if the grid does.
    pub fn cell_of(&self, p: Point) -> Option<usize> {
        let i = ((p.x - self.origin.x) / self.h).floor();
        let j = ((p.y - self.origin.y) / self.h).floor();
        if i < 0.0 || j < 0.0 || i >= self.nx as f64 || j >= self.ny as f64 {
            return None;
        }
        Some(j as usize * self.nx + i as usize)
    }

    /// The material's top at `p` (minus infinity off the grid).
    pub fn top_at(&self, p: Point) -> f32 {
        self.cell_of(p).map_or(f32::NEG_INFINITY, |k| self.top[k])
    }

    /// Cuts with a flat end of radius `r` moving straight from `from` to `to` (Z: the
    /// tool's bottom): every cell whose centre the disc passes over is lowered to the lowest
    /// bottom that passes over it. `done_a` says the disc at `from` has already been cut
    /// there (the tool arrived), so where the move does not go down those cells are
    /// skipped. `each(k, old, new)` is called for every cell lowered.
    pub fn cut(
        &mut self,
        from: crate::toolpath::P3,
        to: crate::toolpath::P3,
        r: f64,
        done_a: bool,
        mut each: impl FnMut(usize, f32, f32),
    ) {
        let (a, za, b, zb) = (from.xy(), from.z, to.xy(), to.z);
        let d = b - a;
        let len = d.len();
        let skip_a = done_a && zb >= za - 1e-12;
        let (ymin, ymax) = (a.y.min(b.y) - r, a.y.max(b.y) + r);
        let j0 = (((ymin - self.origin.y) / self.h - 0.5).ceil().max(0.0)) as usize;
        let j1f = ((ymax - self.origin.y) / self.h - 0.5).floor();
        if j1f < 0.0 {
            return;
        }
        let j1 = (j1f as usize).min(self.ny.saturating_sub(1));
        let t = if len > 0.0 {
            d * (1.0 / len)
        } else {
            Point::new(1.0, 0.0)
        };
        let n = t.perp();
        for j in j0..=j1 {
            let y = self.origin.y + (j as f64 + 0.5) * self.h;
            let Some((x0, x1)) = capsule_row(a, b, t, n, len, r, y) else {
                continue;
            };
            let skip = if skip_a { disc_row(a, r, y) } else { None };
            let i0 = (((x0 - self.origin.x) / self.h - 0.5).ceil().max(0.0)) as usize;
            let i1f = ((x1 - self.origin.x) / self.h - 0.5).floor();
            if i1f < 0.0 {
                continue;
            }
            let i1 = (i1f as usize).min(self.nx.saturating_sub(1));
            for i in i0..=i1 {
                let x = self.origin.x + (i as f64 + 0.5) * self.h;
                if let Some((s0, s1)) = skip {
                    if x > s0 && x < s1 {
                        continue;
                    }
                }
                let k = j * self.nx + i;
                let old = self.top[k];
                if old == f32::NEG_INFINITY {
                    continue;
                }
                let z = lowest_bottom(a, za, zb, t, len, r, Point::new(x, y));
                let Some(z) = z else { continue };
                let z = z as f32;
                if z < old {
                    self.top[k] = z;
                    each(k, old, z);
                }
            }
        }
    }

    /// Marks (true) every cell whose centre lies inside one of `regions`, by scan lines over
    /// the boundaries flattened to within `h / 8`.
    pub fn inside(&self, regions: &[Region]) -> Vec<bool> {
        let mut edges: Vec<(Point, Point)> = Vec::new();
        for r in regions {
            for pl in r.boundaries() {
                for s in pl.segments() {
                    let pts = flatten_segment(&s, self.h / 8.0);
                    for w in pts.windows(2) {
                        edges.push((w[0], w[1]));
                    }
                }
            }
        }
        // edges by the rows they cross
        let mut rows: Vec<Vec<usize>> = vec![Vec::new(); self.ny];
        for (e, (p, q)) in edges.iter().enumerate() {
            let (lo, hi) = (p.y.min(q.y), p.y.max(q.y));
            let j0 = ((lo - self.origin.y) / self.h - 0.5).ceil().max(0.0) as usize;
            let j1 = ((hi - self.origin.y) / self.h - 0.5).floor();
            if j1 < 0.0 {
                continue;
            }
            for row in rows
                .iter_mut()
                .take((j1 as usize + 1).min(self.ny))
                .skip(j0)
            {
                row.push(e);
            }
        }
        let mut mark = vec![false; self.nx * self.ny];
        let mut xs: Vec<f64> = Vec::new();
        for (j, row) in rows.iter().enumerate() {
            let y = self.origin.y + (j as f64 + 0.5) * self.h;
            xs.clear();
            for &e in row {
                let (p, q) = edges[e];
                // half-open in y so a vertex on the row counts once
                if (p.y <= y) != (q.y <= y) {
                    xs.push(p.x + (y - p.y) / (q.y - p.y) * (q.x - p.x));
                }
            }
            xs.sort_by(f64::total_cmp);
            for pair in xs.chunks_exact(2) {
                let i0 = ((pair[0] - self.origin.x) / self.h - 0.5).ceil().max(0.0) as usize;
                let i1 = ((pair[1] - self.origin.x) / self.h - 0.5).floor();
                if i1 < 0.0 {
                    continue;
                }
                for i in i0..=(i1 as usize).min(self.nx - 1) {
                    mark[j * self.nx + i] = true;
                }
            }
        }
        mark
    }

    /// For every cell, the distance in mm from its centre to the centre of the nearest
    /// cell where `set` is true (infinity when there is none): an exact Euclidean distance
    /// transform (Felzenszwalb & Huttenlocher 2012) between cell centres.
    pub fn distance_to(&self, set: &[bool]) -> Vec<f64> {
        let (nx, ny) = (self.nx, self.ny);
        let big = 1e20;
        let mut f: Vec<f64> = set.iter().map(|&s| if s { 0.0 } else { big }).collect();
        let mut buf = vec![0.0; nx.max(ny)];
        let mut out = vec![0.0; nx.max(ny)];
        for j in 0..ny {
            buf[..nx].copy_from_slice(&f[j * nx..(j + 1) * nx]);
            edt_1d(&buf[..nx], &mut out[..nx]);
            f[j * nx..(j + 1) * nx].copy_from_slice(&out[..nx]);
        }
        for i in 0..nx {
            for j in 0..ny {
                buf[j] = f[j * nx + i];
            }
            edt_1d(&buf[..ny], &mut out[..ny]);
            for j in 0..ny {
                f[j * nx + i] = out[j];
            }
        }
        f.into_iter()
            .map(|d2| {
                if d2 >= big * 0.5 {
                    f64::INFINITY
                } else {
                    d2.sqrt() * self.h
                }
            })
            .collect()
    }
}

/// One row of the squared distance transform: `d[q] = min_p (q - p)² + f[p]`.
fn edt_1d(f: &[f64], d: &mut [f64]) {
    let n = f.len();
    if n == 0 {
        return;
    }
    let mut v = vec![0usize; n];
    let mut z = vec![0.0f64; n + 1];
    let mut k = 0usize;
    v[0] = 0;
    z[0] = f64::NEG_INFINITY;
    z[1] = f64::INFINITY;
    let s = |q: usize, p: usize| {
        ((f[q] + (q * q) as f64) - (f[p] + (p * p) as f64)) / (2.0 * (q as f64 - p as f64))
    };
    for q in 1..n {
        let mut sq = s(q, v[k]);
        while sq <= z[k] {
            k -= 1;
            sq = s(q, v[k]);
        }
        k += 1;
        v[k] = q;
        z[k] = sq;
        z[k + 1] = f64::INFINITY;
    }
    k = 0;
    for (q, dq) in d.iter_mut().enumerate() {
        while z[k + 1] < q as f64 {
            k += 1;
        }
        let p = v[k];
        let dx = q as f64 - p as f64;
        *dq = dx * dx + f[p];
    }
}

/// The x-interval of row `y` inside the capsule of radius `r` about the segment a→b
/// (unit direction `t`, normal `n`, length `len`).
fn capsule_row(
    a: Point,
    b: Point,
    t: Point,
    n: Point,
    len: f64,
    r: f64,
    y: f64,
) -> Option<(f64, f64)> {
    let mut lo = f64::INFINITY;
    let mut hi = f64::NEG_INFINITY;
    for c in [a, b] {
        if let Some((x0, x1)) = disc_row(c, r, y) {
            lo = lo.min(x0);
            hi = hi.max(x1);
        }
    }
    if len > 0.0 {
        // the band: |n·(p - a)| ≤ r and 0 ≤ t·(p - a) ≤ len, linear in x along the row
        let mut x0 = f64::NEG_INFINITY;
        let mut x1 = f64::INFINITY;
        let mut ok = true;
        for (u, lo_v, hi_v) in [(n, -r, r), (t, 0.0, len)] {
            // u.x * x + u.y * (y - a.y) - u.x * a.x in [lo_v, hi_v]
            let c = u.y * (y - a.y) - u.x * a.x;
            if u.x.abs() < 1e-15 {
                if c < lo_v || c > hi_v {
                    ok = false;
                }
            } else {
                let (p, q) = ((lo_v - c) / u.x, (hi_v - c) / u.x);
                x0 = x0.max(p.min(q));
                x1 = x1.min(p.max(q));
            }
        }
        if ok && x0 <= x1 {
            lo = lo.min(x0);
            hi = hi.max(x1);
        }
    }
    (lo <= hi).then_some((lo, hi))
}

/// The x-interval of row `y` inside the disc of radius `r` about `c`.
fn disc_row(c: Point, r: f64, y: f64) -> Option<(f64, f64)> {
    let dy = y - c.y;
    let w2 = r * r - dy * dy;
    (w2 >= 0.0).then(|| {
        let w = w2.sqrt();
        (c.x - w, c.x + w)
    })
}

/// The lowest bottom of the tool over `p` while it moves from `a` (at `za`) along `t` for
/// `len` mm to `zb` (Z linear along the move), if the disc passes over `p` at all.
fn lowest_bottom(a: Point, za: f64, zb: f64, t: Point, len: f64, r: f64, p: Point) -> Option<f64> {
    if (zb - za).abs() < 1e-15 {
        return Some(za);
    }
    let v = p - a;
    let along = v.dot(t);
    let across = v.dot(t.perp());
    let w2 = r * r - across * across;
    if w2 < 0.0 {
        return None;
    }
    let w = w2.sqrt();
    let (s0, s1) = ((along - w).max(0.0), (along + w).min(len));
    if s0 > s1 + 1e-12 {
        return None;
    }
    let z = |s: f64| {
        if len > 0.0 {
            za + (zb - za) * (s / len)
        } else {
            zb
        }
    };
    Some(z(s0).min(z(s1)))
}

/// The points of a segment, arcs as chords straying at most `sag` from the arc.
pub fn flatten_segment(s: &Segment, sag: f64) -> Vec<Point> {
    match *s {
        Segment::Line { a, b } => vec![a, b],
        Segment::Arc { radius, .. } => {
            let sweep = s.sweep().abs();
            let step = if radius > sag {
                2.0 * (1.0 - sag / radius).acos()
            } else {
                sweep
            };
            let k = ((sweep / step.max(1e-6)).ceil() as usize).clamp(1, 100_000);
            (0..=k).map(|i| s.point_at(i as f64 / k as f64)).collect()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::Polyline;

    #[test]
    fn the_distance_transform_is_euclidean() {
        let g = Grid::new(Point::new(0.0, 0.0), 1.0, 20, 10);
        let mut set = vec![false; 200];
        set[3 * 20 + 4] = true;
        let d = g.distance_to(&set);
        assert_eq!(d[3 * 20 + 4], 0.0);
        assert!((d[7 * 20 + 7] - 5.0).abs() < 1e-12, "{}", d[7 * 20 + 7]);
        assert!((d[0] - 5.0).abs() < 1e-12);
        assert!(g.distance_to(&[false; 200])[5].is_infinite());
    }

    #[test]
    fn a_circle_fills_its_area_and_a_cut_lowers_its_capsule() {
        let mut g = Grid::new(Point::new(-10.0, -10.0), 0.1, 200, 200);
        let inside = g.inside(&[Region::new(Polyline::circle(Point::default(), 5.0), vec![])]);
        let area = inside.iter().filter(|&&b| b).count() as f64 * 0.01;
        assert!((area - std::f64::consts::PI * 25.0).abs() < 0.3, "{area}");
        g.top.iter_mut().for_each(|t| *t = 0.0);
        let mut lowered = 0;
        g.cut(
            crate::toolpath::P3::new(-4.0, 0.0, -1.0),
            crate::toolpath::P3::new(4.0, 0.0, -1.0),
            1.0,
            false,
            |_, _, _| lowered += 1,
        );
        let want = (8.0 * 2.0 + std::f64::consts::PI) / 0.01;
        assert!(
            (lowered as f64 - want).abs() / want < 0.02,
            "{lowered} vs {want}"
        );
        assert_eq!(g.top_at(Point::new(0.0, 0.95)), -1.0);
        assert_eq!(g.top_at(Point::new(0.0, 1.05)), 0.0);
    }
}
