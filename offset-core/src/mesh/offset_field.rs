//! The trimmed mesh offset: the level set at the offset distance of the part's exact signed
//! distance, contoured by marching tetrahedra.
//!
//! Where the offsets of different faces interfere (a slot narrower than twice the distance,
//! a fillet of smaller radius than it, touching bodies) the multiple-normal offset's faces
//! cross, and trimming them means cutting every crossing face along the curves where the
//! sheets meet and stitching the pieces — a mesh arrangement, fragile in floating point.
//! Contouring the distance instead cannot cross by construction:
//!
//! - The signed distance s(p) of a grid point is the exact distance to the nearest triangle
//!   (a BVH query, no approximation), negative inside the part. Inside is decided by the
//!   winding number along a vertical ray (the signs of the faces the ray crosses above the
//!   point, counted once per crossing by a tie-break that moves the point by (ε, ε²)), so
//!   several shells, overlapping and touching bodies are inside where any one of them is.
//!   Faces that two bodies share (the same three vertices, opposite ways) are inside the
//!   union and dropped first.
//! - The grid is cut into blocks of 8³ cells; since s is 1-Lipschitz, a block whose corner
//!   is farther than its diagonal from the level s = d holds none of it and is skipped, so
//!   only a band round the offset surface is evaluated.
//! - Each cell is split into the six tetrahedra about its diagonal (Kuhn's triangulation,
//!   which neighbouring cells share). A tetrahedron with corners on both sides of the level
//!   gives one or two triangles whose corners lie on its edges, each found by bisection
//!   (regula falsi) on s = d along the edge, so every vertex is at the distance to well
//!   under the tolerance. Corners at the level count as outside, so no vertex sits on a
//!   grid point.
//! - Every triangle lies inside its tetrahedron and meets the neighbouring ones only in the
//!   shared segment of a common face, so the output has no self-intersection, and every
//!   edge is shared by exactly two triangles turning opposite ways (each is turned to face
//!   from the corners inside the offset to those outside).
//! - The error left is that of a flat triangle across a curved or creased level: the grid
//!   step starts from the tolerance and is refined until the sampled worst error is within
//!   it (or the point budget says which tolerance is reachable).

use super::bvh::Bvh;
use super::offset::measure_error;
use super::FastMap;
use super::{Mesh, MeshError, V3};
use rayon::prelude::*;

/// Cells per block side of the band search.
const BLOCK: usize = 8;

/// The most grid points one contouring may evaluate.
pub const FIELD_POINTS: usize = 30_000_000;

/// The most vertical lines (columns of the winding number) of one contouring's grid.
pub const FIELD_COLUMNS: usize = 4_000_000;

/// A contoured offset: the mesh, the grid step and the sampled worst distance error.
pub(crate) struct FieldOffset {
    pub mesh: Mesh,
    pub step: f64,
    pub worst: f64,
}

/// Whether every edge of `m` is run as often one way as the other (a closed, consistently
/// oriented set of shells, non-manifold edges allowed): the condition for the winding number
/// to tell inside from outside.
pub(crate) fn oriented_closed(m: &Mesh) -> bool {
    let mut count: FastMap<(u32, u32), i64> = FastMap::default();
    for f in &m.faces {
        for k in 0..3 {
            let (a, b) = (f[k], f[(k + 1) % 3]);
            if a == b {
                continue;
            }
            let (key, s) = if a < b { ((a, b), 1) } else { ((b, a), -1) };
            *count.entry(key).or_insert(0) += s;
        }
    }
    count.values().all(|&c| c == 0)
}

/// The faces of `m` without the pairs that two bodies share (the same vertices, turning
/// opposite ways): such a face lies inside the union.
fn outer_faces(m: &Mesh) -> Vec<[V3; 3]> {
    let key = |f: &[u32; 3]| {
        let mut k = *f;
        k.sort_unstable();
        k
    };
    let mut by_key: FastMap<[u32; 3], Vec<usize>> = FastMap::default();
    for (i, f) in m.faces.iter().enumerate() {
        by_key.entry(key(f)).or_default().push(i);
    }
    let mut drop = vec![false; m.faces.len()];
    for list in by_key.values() {
        if list.len() < 2 {
            continue;
        }
        // pair faces of opposite turn: a rotation of [a, b, c] turns one way, of [a, c, b]
        // the other
        let turn = |f: &[u32; 3]| {
            let k = f
                .iter()
                .position(|&x| x == f.iter().copied().min().unwrap())
                .unwrap();
            f[(k + 1) % 3] < f[(k + 2) % 3]
        };
        let (fw, bw): (Vec<usize>, Vec<usize>) = list.iter().partition(|&&i| turn(&m.faces[i]));
        for (&a, &b) in fw.iter().zip(&bw) {
            drop[a] = true;
            drop[b] = true;
        }
    }
    (0..m.faces.len())
        .filter(|&i| !drop[i])
        .map(|i| m.triangle(i))
        .collect()
}

/// The winding numbers of the grid's vertical lines: per column, the heights where the line
/// crosses a face and the sum of the crossings' signs above each.
struct Columns {
    nx: usize,
    /// per column: (z, winding above z) sorted by z
    lines: Vec<Vec<(f64, i32)>>,
}

impl Columns {
    fn new(tris: &[[V3; 3]], x0: f64, y0: f64, h: f64, nx: usize, ny: usize) -> Columns {
        let mut lines: Vec<Vec<(f64, i32)>> = vec![Vec::new(); nx * ny];
        for t in tris {
            let [a, b, c] = *t;
            let area = (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x);
            if area == 0.0 {
                continue; // vertical: never crossed by a vertical line in general position
            }
            let sign = if area > 0.0 { 1 } else { -1 };
            // counter-clockwise in the xy plane
            let (p, q, r) = if area > 0.0 { (a, b, c) } else { (a, c, b) };
            let lo = a.min(b).min(c);
            let hi = a.max(b).max(c);
            let i0 = ((lo.x - x0) / h).ceil().max(0.0) as usize;
            let i1 = (((hi.x - x0) / h).floor() as isize).min(nx as isize - 1);
            let j0 = ((lo.y - y0) / h).ceil().max(0.0) as usize;
            let j1 = (((hi.y - y0) / h).floor() as isize).min(ny as isize - 1);
            if i1 < 0 || j1 < 0 {
                continue;
            }
            for j in j0..=j1 as usize {
                let y = y0 + j as f64 * h;
                for i in i0..=i1 as usize {
                    let x = x0 + i as f64 * h;
                    if left(p, q, x, y) && left(q, r, x, y) && left(r, p, x, y) {
                        // the plane's height at (x, y)
                        let n = (b - a).cross(c - a);
                        let z = a.z - (n.x * (x - a.x) + n.y * (y - a.y)) / n.z;
                        lines[i + nx * j].push((z, sign));
                    }
                }
            }
        }
        for l in &mut lines {
            l.sort_by(|u, v| u.0.total_cmp(&v.0));
            let mut above = 0;
            for e in l.iter_mut().rev() {
                above += e.1;
                e.1 = above;
            }
        }
        Columns { nx, lines }
    }

    /// The winding number at height z of column (i, j).
    fn winding(&self, i: usize, j: usize, z: f64) -> i32 {
        let l = &self.lines[i + self.nx * j];
        let k = l.partition_point(|e| e.0 <= z);
        l.get(k).map_or(0, |e| e.1)
    }
}

/// Whether (x, y) moved by (ε, ε²) lies left of the line from p to q: exactly one of two
/// triangles sharing an edge holds a point on it.
fn left(p: V3, q: V3, x: f64, y: f64) -> bool {
    let o = (q.x - p.x) * (y - p.y) - (q.y - p.y) * (x - p.x);
    if o != 0.0 {
        return o > 0.0;
    }
    let e = -(q.y - p.y);
    if e != 0.0 {
        return e > 0.0;
    }
    q.x - p.x > 0.0
}

/// The grid and the distance queries of one contouring.
struct Field<'a> {
    tris: &'a [[V3; 3]],
    bvh: &'a Bvh,
    cols: Columns,
    origin: V3,
    h: f64,
    n: [usize; 3],
    d: f64,
    /// The level of the unsigned distance (an open surface's, which has no inside): s is
    /// the distance itself and d is |d|.
    unsigned: bool,
}

impl Field<'_> {
    fn point(&self, i: usize, j: usize, k: usize) -> V3 {
        self.origin + V3::new(i as f64, j as f64, k as f64) * self.h
    }

    fn id(&self, i: usize, j: usize, k: usize) -> u64 {
        (i + self.n[0] * (j + self.n[1] * k)) as u64
    }

    fn ijk(&self, id: u64) -> [usize; 3] {
        let id = id as usize;
        [
            id % self.n[0],
            (id / self.n[0]) % self.n[1],
            id / (self.n[0] * self.n[1]),
        ]
    }

    /// s − d at a grid point (negative: inside the offset).
    fn value(&self, i: usize, j: usize, k: usize) -> f64 {
        let p = self.point(i, j, k);
        let dist = self.bvh.nearest(self.tris, p).0;
        let s = if !self.unsigned && self.cols.winding(i, j, p.z) >= 1 {
            -dist
        } else {
            dist
        };
        s - self.d
    }

    /// s − d off the grid, near the level: within a step of it the sign of s is the sign of
    /// d (the step is at most |d| / 2), so the unsigned distance serves.
    fn value_near(&self, p: V3) -> f64 {
        let dist = self.bvh.nearest(self.tris, p).0;
        if self.d > 0.0 || self.unsigned {
            dist - self.d
        } else {
            -dist - self.d
        }
    }

    /// The point on the segment from `a` (inside, value fa < 0) to `b` (outside, fb ≥ 0)
    /// where s = d, by regula falsi (Illinois), kept off the ends by a millionth of the
    /// segment.
    fn crossing(&self, a: V3, mut fa: f64, b: V3, mut fb: f64, tol: f64) -> V3 {
        let (mut lo, mut hi) = (0.0f64, 1.0f64);
        let mut side = 0;
        let mut t = 0.5;
        for _ in 0..60 {
            t = if fb - fa > 0.0 {
                lo + (hi - lo) * (-fa / (fb - fa))
            } else {
                0.5 * (lo + hi)
            };
            t = t.clamp(lo + 1e-3 * (hi - lo), hi - 1e-3 * (hi - lo));
            let f = self.value_near(a.lerp(b, t));
            if f.abs() <= tol || hi - lo < 1e-12 {
                break;
            }
            if f < 0.0 {
                lo = t;
                fa = f;
                if side == -1 {
                    fb *= 0.5;
                }
                side = -1;
            } else {
                hi = t;
                fb = f;
                if side == 1 {
                    fa *= 0.5;
                }
                side = 1;
            }
        }
        a.lerp(b, t.clamp(1e-6, 1.0 - 1e-6))
    }
}

/// The six tetrahedra of a unit cell about its diagonal from corner 0 to corner 7 (corner
/// bits: 1 = +x, 2 = +y, 4 = +z).
const TETS: [[usize; 4]; 6] = [
    [0, 1, 3, 7],
    [0, 1, 5, 7],
    [0, 2, 3, 7],
    [0, 2, 6, 7],
    [0, 4, 5, 7],
    [0, 4, 6, 7],
];

/// Contours the level s = d of the closed, oriented mesh `m` at grid step `h` (`unsigned`:
/// the level of the distance to `m`, whatever its sides, at d > 0).
fn contour(
    m: &Mesh,
    tris: &[[V3; 3]],
    bvh: &Bvh,
    d: f64,
    h: f64,
    tol: f64,
    unsigned: bool,
) -> Result<(Mesh, usize), MeshError> {
    let (lo, hi) = m.bounds().ok_or(MeshError::Empty {
        name: m.name.clone(),
    })?;
    let margin = d.max(0.0) + 2.0 * h;
    // the origin off any round number, so grid lines rarely meet the part's edges
    let origin = lo - V3::new(margin, margin, margin) - V3::new(0.1372, 0.2913, 0.4137) * h;
    let span = hi - origin + V3::new(margin, margin, margin);
    let n = [
        (span.x / h).ceil() as usize + 2,
        (span.y / h).ceil() as usize + 2,
        (span.z / h).ceil() as usize + 2,
    ];
    if n[0] * n[1] > FIELD_COLUMNS {
        return Err(MeshError::BadParam(format!(
            "{}: the trimmed offset at a grid step of {h:.4} mm needs {} × {} columns, more than the budget of {}: ask for a larger tolerance",
            m.name,
            n[0],
            n[1],
            FIELD_COLUMNS
        )));
    }
    let cols = if unsigned {
        Columns {
            nx: n[0],
            lines: Vec::new(),
        }
    } else {
        Columns::new(tris, origin.x, origin.y, h, n[0], n[1])
    };
    let f = Field {
        tris,
        bvh,
        cols,
        origin,
        h,
        n,
        d,
        unsigned,
    };
    let nb = [
        (n[0] - 1).div_ceil(BLOCK),
        (n[1] - 1).div_ceil(BLOCK),
        (n[2] - 1).div_ceil(BLOCK),
    ];
    let reach = BLOCK as f64 * h * 3f64.sqrt();
    let blocks: Vec<[usize; 3]> = (0..nb[0] * nb[1] * nb[2])
        .into_par_iter()
        .map(|b| [b % nb[0], (b / nb[0]) % nb[1], b / (nb[0] * nb[1])])
        .filter(|b| {
            let v = f.value(b[0] * BLOCK, b[1] * BLOCK, b[2] * BLOCK);
            v.abs() <= reach
        })
        .collect();
    let points = blocks.len() * (BLOCK + 1).pow(3);
    if points > FIELD_POINTS {
        return Err(MeshError::BadParam(format!(
            "{}: the trimmed offset at a grid step of {h:.4} mm would evaluate {points} points, more than the budget of {FIELD_POINTS}: ask for a larger tolerance",
            m.name
        )));
    }
    // the values at every corner of the blocks in the band
    let values: FastMap<u64, f64> = blocks
        .par_iter()
        .flat_map_iter(|b| {
            let f = &f;
            let end = |a: usize| (b[a] * BLOCK + BLOCK).min(n[a] - 1);
            let (e0, e1, e2) = (end(0), end(1), end(2));
            (b[2] * BLOCK..=e2).flat_map(move |k| {
                (b[1] * BLOCK..=e1).flat_map(move |j| {
                    (b[0] * BLOCK..=e0).map(move |i| (f.id(i, j, k), f.value(i, j, k)))
                })
            })
        })
        .collect();
    // the tetrahedra's triangles, by the grid edges their corners lie on
    let mut edges: FastMap<(u64, u64), u32> = FastMap::default();
    let mut edge_list: Vec<(u64, u64)> = Vec::new();
    let mut faces: Vec<[u32; 3]> = Vec::new();
    // per face: a direction from inside to outside the offset, to turn it
    let mut outward: Vec<V3> = Vec::new();
    let mut edge_at = |a: u64, b: u64| -> u32 {
        let key = (a.min(b), a.max(b));
        *edges.entry(key).or_insert_with(|| {
            edge_list.push(key);
            (edge_list.len() - 1) as u32
        })
    };
    for b in &blocks {
        let end = |a: usize| (b[a] * BLOCK + BLOCK).min(n[a] - 1);
        for k in b[2] * BLOCK..end(2) {
            for j in b[1] * BLOCK..end(1) {
                for i in b[0] * BLOCK..end(0) {
                    let ids: [u64; 8] = std::array::from_fn(|c| {
                        f.id(i + (c & 1), j + ((c >> 1) & 1), k + ((c >> 2) & 1))
                    });
                    let vals: [f64; 8] = std::array::from_fn(|c| values[&ids[c]]);
                    let inside = vals.map(|v| v < 0.0);
                    if inside.iter().all(|&x| x) || inside.iter().all(|&x| !x) {
                        continue;
                    }
                    let corner = |c: usize| {
                        V3::new((c & 1) as f64, ((c >> 1) & 1) as f64, ((c >> 2) & 1) as f64)
                    };
                    for t in TETS {
                        let (ins, outs): (Vec<usize>, Vec<usize>) =
                            t.iter().partition(|&&c| inside[c]);
                        if ins.is_empty() || outs.is_empty() {
                            continue;
                        }
                        let mean = |l: &[usize]| {
                            l.iter().fold(V3::ZERO, |s, &c| s + corner(c)) / l.len() as f64
                        };
                        let dir = mean(&outs) - mean(&ins);
                        let mut tri = |p: [(usize, usize); 3]| {
                            faces.push(p.map(|(a, b)| edge_at(ids[a], ids[b])));
                            outward.push(dir);
                        };
                        match (ins.len(), outs.len()) {
                            (1, 3) => {
                                tri([(ins[0], outs[0]), (ins[0], outs[1]), (ins[0], outs[2])])
                            }
                            (3, 1) => {
                                tri([(ins[0], outs[0]), (ins[1], outs[0]), (ins[2], outs[0])])
                            }
                            _ => {
                                let q = [
                                    (ins[0], outs[0]),
                                    (ins[0], outs[1]),
                                    (ins[1], outs[1]),
                                    (ins[1], outs[0]),
                                ];
                                tri([q[0], q[1], q[2]]);
                                tri([q[0], q[2], q[3]]);
                            }
                        }
                    }
                }
            }
        }
    }
    let vertex_tol = 1e-3 * tol;
    let vertices: Vec<V3> = edge_list
        .par_iter()
        .map(|&(a, b)| {
            let (pa, pb) = (f.ijk(a), f.ijk(b));
            let (va, vb) = (values[&a], values[&b]);
            let (qa, qb) = (f.point(pa[0], pa[1], pa[2]), f.point(pb[0], pb[1], pb[2]));
            if va < 0.0 {
                f.crossing(qa, va, qb, vb, vertex_tol)
            } else {
                f.crossing(qb, vb, qa, va, vertex_tol)
            }
        })
        .collect();
    for (face, dir) in faces.iter_mut().zip(&outward) {
        let [a, b, c] = face.map(|v| vertices[v as usize]);
        if (b - a).cross(c - a).dot(*dir) < 0.0 {
            face.swap(1, 2);
        }
    }
    Ok((
        Mesh::new(format!("{} offset {d}", m.name), vertices, faces),
        points,
    ))
}

/// The trimmed offset of the closed, oriented mesh `m` by `d` within `tol`: contoured at a
/// step from the tolerance, refined while the sampled worst error passes it.
pub(crate) fn offset_by_field(m: &Mesh, d: f64, tol: f64) -> Result<FieldOffset, MeshError> {
    let m = if m.volume() < 0.0 {
        m.flipped()
    } else {
        m.clone()
    };
    let tris = outer_faces(&m);
    let bvh = Bvh::new(&tris, false);
    let part = Mesh::from_triangles(&m.name, &tris, 1e-9);
    refined("trimmed", &m.name, &part, d, tol, |h| {
        contour(&m, &tris, &bvh, d, h, tol, false).map(|(mesh, _points)| mesh)
    })
}

/// Contours with `at_step(h)` from a grid step set by the tolerance and refines the step (up
/// to six times) while the worst error sampled against `part` passes the tolerance. A flat
/// triangle across a crease strays about a third of its size, across a cylinder of radius
/// |d| about 3h²/(8|d|); the error of a crease goes with the step.
fn refined(
    what: &str,
    name: &str,
    part: &Mesh,
    d: f64,
    tol: f64,
    mut at_step: impl FnMut(f64) -> Result<Mesh, MeshError>,
) -> Result<FieldOffset, MeshError> {
    let ad = d.abs();
    let mut h = (3.0 * tol).min((8.0 * ad * tol / 3.0).sqrt()).min(ad / 2.0);
    let mut last = None;
    for _ in 0..6 {
        let mesh = at_step(h)?;
        let (worst, _) = measure_error(part, &mesh, d, 2);
        if worst <= tol {
            return Ok(FieldOffset {
                mesh,
                step: h,
                worst,
            });
        }
        last = Some(worst);
        h *= (0.9 * tol / worst).clamp(0.3, 0.8);
    }
    Err(MeshError::BadParam(format!(
        "{name}: the {what} offset by {d} reaches a worst error of {:.4} mm at a grid step of {h:.4} mm, not the tolerance {tol}: ask for a larger tolerance",
        last.unwrap_or(f64::NAN)
    )))
}

/// The one-sided offset of the open, consistently turned surface `m` by `d` within `tol`:
/// the level at |d| of the distance to the surface, contoured as [`offset_by_field`] does
/// (so no two faces cross and every point is at |d|), keeping the faces on the side the
/// surface's normals point to (d > 0) or the other (d < 0). A face's side is the sign of its
/// centre's offset from the nearest point of the surface along the surface's pseudonormal
/// there (the face's normal inside a face, the angle-weighted normal at a vertex, the sum
/// of the two faces' at an edge: Bærentzen & Aanæs 2005), so round a free edge a quarter
/// turn of the tube about it is kept, up to the plane of the faces along it. The result's
/// faces turn as the input's do (away from it for d > 0, towards it for d < 0); it is
/// open, its rim within a grid step of that cut.
pub(crate) fn one_sided_by_field(m: &Mesh, d: f64, tol: f64) -> Result<FieldOffset, MeshError> {
    let ad = d.abs();
    let tris: Vec<[V3; 3]> = m.triangles().collect();
    let bvh = Bvh::new(&tris, false);
    let normals: Vec<V3> = (0..m.faces.len()).map(|f| m.face_normal(f)).collect();
    // pseudonormals at vertices (angle-weighted) and along edges (sum of the faces')
    let mut at_vertex = vec![V3::ZERO; m.vertices.len()];
    let mut along_edge: FastMap<(u32, u32), V3> = FastMap::default();
    for (f, face) in m.faces.iter().enumerate() {
        let t = tris[f];
        for k in 0..3 {
            let (u, v) = (t[(k + 1) % 3] - t[k], t[(k + 2) % 3] - t[k]);
            let (lu, lv) = (u.len(), v.len());
            if lu > 0.0 && lv > 0.0 {
                let angle = (u.dot(v) / (lu * lv)).clamp(-1.0, 1.0).acos();
                at_vertex[face[k] as usize] += normals[f] * angle;
            }
            let (a, b) = (face[k], face[(k + 1) % 3]);
            let e = along_edge.entry((a.min(b), a.max(b))).or_insert(V3::ZERO);
            *e += normals[f];
        }
    }
    let side = |p: V3| -> f64 {
        let (_, f) = bvh.nearest(&tris, p);
        if f == usize::MAX {
            return 0.0;
        }
        let t = tris[f];
        let q = super::v3::closest_on_triangle(p, &t);
        let face = m.faces[f];
        let size = (t[1] - t[0]).len().max((t[2] - t[0]).len()).max(1e-12);
        let eps = 1e-7 * size;
        let mut n = normals[f];
        if let Some(k) = (0..3).find(|&k| q.dist(t[k]) <= eps) {
            n = at_vertex[face[k] as usize];
        } else if let Some(k) = (0..3).find(|&k| {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            q.dist(super::v3::closest_on_segment(q, a, b)) <= eps
        }) {
            let (a, b) = (face[k], face[(k + 1) % 3]);
            n = along_edge[&(a.min(b), a.max(b))];
        }
        (p - q).dot(n)
    };
    refined("one-sided", &m.name, m, d, tol, |h| {
        let (whole, _points) = contour(m, &tris, &bvh, ad, h, tol, true)?;
        // the faces on the asked side, by their centres
        let keep: Vec<usize> = (0..whole.faces.len())
            .into_par_iter()
            .filter(|&f| {
                let [a, b, c] = whole.triangle(f);
                side((a + b + c) / 3.0) * d > 0.0
            })
            .collect();
        let mut index = vec![u32::MAX; whole.vertices.len()];
        let mut vertices = Vec::new();
        let mut faces = Vec::with_capacity(keep.len());
        for f in keep {
            let mut face = whole.faces[f].map(|v| {
                if index[v as usize] == u32::MAX {
                    index[v as usize] = vertices.len() as u32;
                    vertices.push(whole.vertices[v as usize]);
                }
                index[v as usize]
            });
            if d < 0.0 {
                face.swap(1, 2);
            }
            faces.push(face);
        }
        let mesh = Mesh::new(format!("{} offset {d}", m.name), vertices, faces);
        if mesh.faces.is_empty() {
            return Err(MeshError::BadParam(format!(
                "{}: the one-sided offset by {d} has no faces",
                m.name
            )));
        }
        Ok(mesh)
    })
}
