//! The upper envelope of a triangle soup for a cutter: drop-cutter heights on a plan-view
//! grid, and the contours where that height field crosses a level.
//!
//! A 3-axis machine only meets the top of a part, so the heights a cutter drops to are all
//! that roughing and waterlines need, whatever the mesh's topology (open, non-manifold,
//! several shells, flipped faces, undercuts): the tool at tip height z collides with the
//! part exactly where the drop-cutter height is above z (the tool reaches up without end,
//! so a lower tip only collides more).
//!
//! Contours are traced by marching squares over the grid's cells with the marked corners
//! (the ones a predicate picks) on the left: loops run counter-clockwise round marked
//! regions and clockwise round their holes, as [`super::slice_at`] does round material.
//! A saddle cell joins its two marked corners. Where a contour crosses a grid edge is for
//! the caller to say: the edge's middle (then the loops hold every cell whose four corners
//! are marked, the conservative choice of roughing) or a point found on the edge by
//! bisection (waterlines).

use super::dropcutter::DropCutter;
use super::FastMap;
use crate::geom::{Point, Polyline};
use rayon::prelude::*;

/// Drop-cutter heights over a regular plan-view grid: point (i, j) at
/// (x0 + i·h, y0 + j·h).
#[derive(Clone, Debug)]
pub struct HeightField {
    pub x0: f64,
    pub y0: f64,
    pub h: f64,
    pub nx: usize,
    pub ny: usize,
    /// Row-major heights, `z[j * nx + i]`.
    pub z: Vec<f64>,
}

/// The grid step for a plan-view area of `w` × `d` mm: `want`, or coarser where that
/// would take more than `budget` points.
pub fn grid_step(w: f64, d: f64, want: f64, budget: usize) -> f64 {
    let need = ((w.max(0.0) + want) * (d.max(0.0) + want) / budget as f64).sqrt();
    want.max(need)
}

impl HeightField {
    /// The heights of `dc` over the grid of step `h` covering [x_min, y_min, x_max,
    /// y_max] (one step more on every side), none lower than `floor`.
    pub fn new(dc: &DropCutter, area: [f64; 4], h: f64, floor: f64) -> HeightField {
        let x0 = area[0] - h;
        let y0 = area[1] - h;
        let nx = ((area[2] - area[0]) / h).ceil() as usize + 3;
        let ny = ((area[3] - area[1]) / h).ceil() as usize + 3;
        let mut z = vec![floor; nx * ny];
        z.par_chunks_mut(nx).enumerate().for_each(|(j, row)| {
            let y = y0 + j as f64 * h;
            for (i, v) in row.iter_mut().enumerate() {
                *v = dc.drop(x0 + i as f64 * h, y, floor);
            }
        });
        HeightField {
            x0,
            y0,
            h,
            nx,
            ny,
            z,
        }
    }

    /// Grid point (i, j) in plan view.
    pub fn point(&self, i: usize, j: usize) -> Point {
        Point::new(self.x0 + i as f64 * self.h, self.y0 + j as f64 * self.h)
    }

    /// The height at grid point (i, j).
    pub fn at(&self, i: usize, j: usize) -> f64 {
        self.z[j * self.nx + i]
    }

    /// The loops round the grid points whose heights `marked` picks, marked side on the
    /// left; `cut(inside, outside)` places the crossing on each grid edge between a marked
    /// point and an unmarked one. The grid's outermost points count as unmarked, so every
    /// loop closes. Collinear points are dropped.
    pub fn contours(
        &self,
        marked: impl Fn(f64) -> bool,
        mut cut: impl FnMut(Point, Point) -> Point,
    ) -> Vec<Polyline> {
        let (nx, ny) = (self.nx, self.ny);
        let on = |i: usize, j: usize| {
            i > 0 && j > 0 && i + 1 < nx && j + 1 < ny && marked(self.z[j * nx + i])
        };
        // a grid edge: (i, j, 0) from (i, j) to (i+1, j); (i, j, 1) from (i, j) to (i, j+1)
        type Key = (u32, u32, u8);
        let mut next: FastMap<Key, Key> = FastMap::default();
        for j in 0..ny.saturating_sub(1) {
            for i in 0..nx.saturating_sub(1) {
                // corners counter-clockwise, and the edge after each one
                let c = [on(i, j), on(i + 1, j), on(i + 1, j + 1), on(i, j + 1)];
                if c.iter().all(|&b| b) || c.iter().all(|&b| !b) {
                    continue;
                }
                let (iu, ju) = (i as u32, j as u32);
                let edges: [Key; 4] = [(iu, ju, 0), (iu + 1, ju, 1), (iu, ju + 1, 0), (iu, ju, 1)];
                // a contour starts where the walk round the cell leaves the marked corners
                // and ends at the next edge where it comes back to them
                for k in 0..4 {
                    if c[k] && !c[(k + 1) % 4] {
                        let mut e = (k + 1) % 4;
                        while c[e] || !c[(e + 1) % 4] {
                            e = (e + 1) % 4;
                        }
                        next.insert(edges[k], edges[e]);
                    }
                }
            }
        }
        let ends = |k: Key| -> (Point, Point) {
            let (i, j) = (k.0 as usize, k.1 as usize);
            let (a, b) = if k.2 == 0 {
                ((i, j), (i + 1, j))
            } else {
                ((i, j), (i, j + 1))
            };
            let (pa, pb) = (self.point(a.0, a.1), self.point(b.0, b.1));
            if on(a.0, a.1) {
                (pa, pb)
            } else {
                (pb, pa)
            }
        };
        let mut starts: Vec<Key> = next.keys().copied().collect();
        starts.sort_unstable();
        let mut done: FastMap<Key, ()> = FastMap::default();
        let mut loops = Vec::new();
        for s in starts {
            if done.contains_key(&s) {
                continue;
            }
            let mut pts: Vec<Point> = Vec::new();
            let mut k = s;
            loop {
                done.insert(k, ());
                let (inside, outside) = ends(k);
                pts.push(cut(inside, outside));
                match next.get(&k) {
                    Some(&n) if n != s && !done.contains_key(&n) => k = n,
                    _ => break,
                }
            }
            let pts = drop_collinear(&pts);
            if pts.len() >= 3 {
                loops.push(Polyline::from_points(&pts, true));
            }
        }
        loops
    }
}

/// The closed loop without its points that lie on the line through their neighbours.
fn drop_collinear(pts: &[Point]) -> Vec<Point> {
    let n = pts.len();
    if n < 4 {
        return pts.to_vec();
    }
    let mut out = Vec::with_capacity(n);
    for k in 0..n {
        let (a, b, c) = (pts[(k + n - 1) % n], pts[k], pts[(k + 1) % n]);
        let cross = (b - a).cross(c - b);
        let scale = (b - a).len() * (c - b).len();
        if cross.abs() > 1e-9 * scale.max(1e-300) {
            out.push(b);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::shapes::cuboid;
    use crate::mesh::{Cutter, V3};

    #[test]
    fn a_box_under_a_small_flat_cutter_is_one_loop_round_it_counter_clockwise() {
        let m = cuboid(V3::ZERO, V3::new(10.0, 6.0, 4.0));
        let dc = DropCutter::new(&m, Cutter::flat(0.2)).unwrap();
        let hf = HeightField::new(&dc, [0.0, 0.0, 10.0, 6.0], 0.5, -1.0);
        let loops = hf.contours(|z| z >= 2.0, |a, b| a.lerp(b, 0.5));
        assert_eq!(loops.len(), 1, "{loops:?}");
        assert!(loops[0].is_ccw());
        // the box grown by the cutter radius, give or take half a grid step
        let area = loops[0].area();
        assert!(area > 10.0 * 6.0 && area < 11.5 * 7.5, "{area}");
    }

    #[test]
    fn a_hole_is_a_clockwise_loop_inside() {
        // a frame: a 10 × 10 plate with a 4 × 4 window, as two shells' worth of boxes
        let mut tris: Vec<[V3; 3]> = Vec::new();
        for (lo, hi) in [
            (V3::new(0.0, 0.0, 0.0), V3::new(10.0, 3.0, 2.0)),
            (V3::new(0.0, 7.0, 0.0), V3::new(10.0, 10.0, 2.0)),
            (V3::new(0.0, 3.0, 0.0), V3::new(3.0, 7.0, 2.0)),
            (V3::new(7.0, 3.0, 0.0), V3::new(10.0, 7.0, 2.0)),
        ] {
            tris.extend(cuboid(lo, hi).triangles());
        }
        let m = crate::mesh::Mesh::from_triangles("frame", &tris, 1e-9);
        let dc = DropCutter::new(&m, Cutter::flat(0.1)).unwrap();
        let hf = HeightField::new(&dc, [0.0, 0.0, 10.0, 10.0], 0.25, -1.0);
        let loops = hf.contours(|z| z >= 1.0, |a, b| a.lerp(b, 0.5));
        assert_eq!(loops.len(), 2, "{loops:?}");
        assert_eq!(loops.iter().filter(|l| l.is_ccw()).count(), 1);
    }
}
