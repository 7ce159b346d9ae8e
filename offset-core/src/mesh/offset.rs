//! Mesh offset by multiple normals per vertex (Kim & Yang 2005): a closed mesh grown (or
//! shrunk) by a distance, its sharp convex edges and corners closed with blend faces.
//!
//! - Around each vertex its faces form a ring. Neighbouring faces whose edge is concave or
//!   flat share the vertex's offset point; across a convex edge the two clusters of normals
//!   are merged, the closest pair first, while the merged point stays within the tolerance
//!   of the offset distance. A cluster's offset point v + w solves n·w = d for the normals
//!   of its faces in the least-squares sense (weighted by the faces' angles at v), so its
//!   faces move exactly d along their normals; its error is the largest of how far a face
//!   of the cluster is from d and how far the point is from d off the vertex's ring.
//! - Each face moves to the offset points of its clusters. Along an edge whose ends
//!   have different clusters on its two sides, a strip of blend faces closes the gap: at
//!   each end an arc of points turns from one cluster's point to the other's about the
//!   vertex (directions interpolated on the sphere, lengths linearly), in steps whose
//!   sagitta stays within a quarter of the tolerance (a flat face between such chords
//!   strays up to about twice as far).
//! - Where three or more clusters meet (a corner) the arcs leave a hole round the vertex;
//!   it is filled with a fan from the hole's mean direction, its spokes split to the same
//!   steps, so the output is closed: every edge is shared by exactly two faces.
//! - A negative distance offsets the turned-over mesh and turns the result back.
//!
//! The multiple-normal offset is not trimmed: a distance larger than a concave feature (a
//! slot narrower than twice it) leaves faces that cross, closer to the part than the
//! distance. [`offset`] therefore samples its worst error and, past the tolerance (or for
//! touching bodies, whose edges have four faces), makes the trimmed offset instead: the
//! exact distance's level set contoured by marching tetrahedra (`offset_field`).

use super::bvh::Bvh;
use super::topology::Topology;
use super::v3::dist_to_triangle;
use super::FastMap;
use super::{Mesh, MeshError, V3};
use serde::{Deserialize, Serialize};

/// Settings of a mesh offset.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct MeshOffsetOptions {
    /// How far the offset surface may stray from the offset distance, mm.
    pub tolerance: f64,
}

impl Default for MeshOffsetOptions {
    fn default() -> Self {
        MeshOffsetOptions { tolerance: 0.01 }
    }
}

/// What an offset made.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct OffsetReport {
    pub faces_in: usize,
    pub faces_out: usize,
    /// Faces moved from the input.
    pub moved_faces: usize,
    /// Blend faces along sharp edges.
    pub edge_blend_faces: usize,
    /// Blend faces at corners.
    pub corner_blend_faces: usize,
    /// Vertices that kept more than one normal.
    pub split_vertices: usize,
    /// How the offset was made.
    #[serde(default)]
    pub method: OffsetMethod,
    /// The grid step of a trimmed (contoured) offset, mm; 0 for multiple normals.
    #[serde(default)]
    pub grid_step: f64,
    /// The worst distance error sampled on the output ([`measure_error`], 3 steps a side
    /// for multiple normals, 2 for the contoured faces), mm.
    #[serde(default)]
    pub worst_error: f64,
}

/// How an offset was made.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OffsetMethod {
    /// Multiple normals per vertex (Kim & Yang 2005), where no offsets interfere.
    #[default]
    MultipleNormals,
    /// Trimmed: the exact distance's level set, contoured by marching tetrahedra
    /// (`offset_field`), where offsets of different faces interfere or bodies touch.
    Trimmed,
    /// One-sided: the input is an open surface (it has no inside), and the result is the
    /// surface at |d| on the side its normals point to (d > 0) or the other (d < 0),
    /// contoured from the exact distance as the trimmed offset is; it is open too.
    OneSided,
}

/// An offset mesh and what made it.
#[derive(Clone, Debug)]
pub struct OffsetResult {
    pub mesh: Mesh,
    pub report: OffsetReport,
}

/// Offsets the closed solid `m` by `distance` (positive grows it, negative shrinks it); an
/// open surface is offset one-sided ([`OffsetMethod::OneSided`]: on the side its normals
/// point to for a positive distance, the other for a negative one).
pub fn offset(
    m: &Mesh,
    distance: f64,
    opts: &MeshOffsetOptions,
) -> Result<OffsetResult, MeshError> {
    if !distance.is_finite() {
        return Err(MeshError::BadParam(format!(
            "the offset distance must be a number, got {distance}"
        )));
    }
    if !(opts.tolerance.is_finite() && opts.tolerance > 0.0) {
        return Err(MeshError::BadParam(format!(
            "the offset tolerance must be a positive number, got {}",
            opts.tolerance
        )));
    }
    if distance == 0.0 {
        let (solid, _) = m.solid()?;
        let faces_in = solid.faces.len();
        return Ok(OffsetResult {
            report: OffsetReport {
                faces_in,
                faces_out: faces_in,
                moved_faces: faces_in,
                edge_blend_faces: 0,
                corner_blend_faces: 0,
                split_vertices: 0,
                method: OffsetMethod::MultipleNormals,
                grid_step: 0.0,
                worst_error: 0.0,
            },
            mesh: solid,
        });
    }
    let solid = match m.solid() {
        Ok(st) => Some(st),
        // touching bodies (an edge of four faces), still closed and oriented: trimmed
        Err(e @ MeshError::NonManifold { .. }) => {
            if !super::offset_field::oriented_closed(m) {
                return Err(e);
            }
            None
        }
        // an open surface has no inside: offset on one side
        Err(MeshError::Open { .. }) => return one_sided(m, distance, opts.tolerance),
        Err(e) => return Err(e),
    };
    if let Some((solid, topo)) = solid {
        let mut r = multiple_normals(&solid, &topo, distance, opts.tolerance);
        let (worst, _) = measure_error(&solid, &r.mesh, distance, 3);
        if worst <= opts.tolerance {
            r.report.worst_error = worst;
            r.mesh.name = format!("{} offset {distance}", m.name);
            return Ok(r);
        }
    }
    // offsets of different faces interfere (the multiple-normal faces cross or stray), or
    // bodies touch: the trimmed offset
    m.check_finite()?;
    let faces_in = m.faces.len();
    let fo = super::offset_field::offset_by_field(m, distance, opts.tolerance)?;
    let mut mesh = fo.mesh;
    mesh.name = format!("{} offset {distance}", m.name);
    Ok(OffsetResult {
        report: OffsetReport {
            faces_in,
            faces_out: mesh.faces.len(),
            moved_faces: 0,
            edge_blend_faces: 0,
            corner_blend_faces: 0,
            split_vertices: 0,
            method: OffsetMethod::Trimmed,
            grid_step: fo.step,
            worst_error: fo.worst,
        },
        mesh,
    })
}

/// The one-sided offset of the open surface `m` (its faces turned consistently, else the
/// side is not defined and the faces turned against their neighbours are named).
fn one_sided(m: &Mesh, distance: f64, tol: f64) -> Result<OffsetResult, MeshError> {
    let r = Topology::new(m).report(m);
    if !r.flipped_faces.is_empty() {
        return Err(MeshError::Flipped {
            name: m.name.clone(),
            count: r.flipped_faces.len(),
            faces: r.flipped_faces,
        });
    }
    let fo = super::offset_field::one_sided_by_field(m, distance, tol)?;
    Ok(OffsetResult {
        report: OffsetReport {
            faces_in: m.faces.len(),
            faces_out: fo.mesh.faces.len(),
            moved_faces: 0,
            edge_blend_faces: 0,
            corner_blend_faces: 0,
            split_vertices: 0,
            method: OffsetMethod::OneSided,
            grid_step: fo.step,
            worst_error: fo.worst,
        },
        mesh: fo.mesh,
    })
}

/// The multiple-normal offset of the closed solid `solid` (a negative distance offsets the
/// turned-over solid and turns the result back).
fn multiple_normals(solid: &Mesh, topo: &Topology, distance: f64, tol: f64) -> OffsetResult {
    if distance < 0.0 {
        let turned = solid.flipped();
        let topo = Topology::new(&turned);
        let mut r = Offsetter::new(&turned, &topo, -distance, tol).run();
        r.mesh = r.mesh.flipped();
        return r;
    }
    Offsetter::new(solid, topo, distance, tol).run()
}

/// The worst distance error of an offset: `out`'s faces sampled (corners, edge points and
/// inner points on a grid of `k` steps a side) and each point's distance to `input`
/// compared with |distance|. Returns (worst error, points sampled).
pub fn measure_error(input: &Mesh, out: &Mesh, distance: f64, k: usize) -> (f64, usize) {
    use rayon::prelude::*;
    let tris: Vec<[V3; 3]> = input.triangles().collect();
    let bvh = Bvh::new(&tris, false);
    let k = k.max(1);
    let d = distance.abs();
    (0..out.faces.len())
        .into_par_iter()
        .map(|f| {
            let t = out.triangle(f);
            let mut worst: f64 = 0.0;
            let mut n = 0;
            for i in 0..=k {
                for j in 0..=(k - i) {
                    let p = t[0]
                        + (t[1] - t[0]) * (i as f64 / k as f64)
                        + (t[2] - t[0]) * (j as f64 / k as f64);
                    worst = worst.max((bvh.nearest(&tris, p).0 - d).abs());
                    n += 1;
                }
            }
            (worst, n)
        })
        .reduce(|| (0.0, 0), |a, b| (a.0.max(b.0), a.1 + b.1))
}

/// One cluster of a vertex's faces: its offset point.
#[derive(Clone, Copy, Debug)]
struct Cluster {
    w: V3,
}

/// An arc of output points between two clusters' points: the axis it turns about (zero:
/// about the vertex) and the points.
type Arc = (V3, Vec<u32>);

struct Offsetter<'a> {
    m: &'a Mesh,
    topo: &'a Topology,
    d: f64,
    tol: f64,
    normals: Vec<V3>,
    /// per face, per corner: the cluster (an index into `clusters`)
    corner_cluster: Vec<[u32; 3]>,
    clusters: Vec<Cluster>,
    /// the source vertex of each cluster
    cluster_vertex: Vec<u32>,
    out_vertices: Vec<V3>,
    /// the output vertex of each cluster's point
    cluster_point: Vec<u32>,
    /// the source vertex of each output vertex
    point_vertex: Vec<u32>,
    arcs: FastMap<(u32, u32), Vec<Arc>>,
    /// for a pair of clusters at a vertex split by a sharp edge: that edge's direction
    pair_axis: FastMap<(u32, u32), V3>,
    vertex_faces: Vec<Vec<u32>>,
}

impl<'a> Offsetter<'a> {
    fn new(m: &'a Mesh, topo: &'a Topology, d: f64, tol: f64) -> Self {
        let normals = (0..m.faces.len()).map(|f| m.face_normal(f)).collect();
        Offsetter {
            m,
            topo,
            d,
            tol,
            normals,
            corner_cluster: vec![[u32::MAX; 3]; m.faces.len()],
            clusters: Vec::new(),
            cluster_vertex: Vec::new(),
            out_vertices: Vec::new(),
            cluster_point: Vec::new(),
            point_vertex: Vec::new(),
            arcs: FastMap::default(),
            pair_axis: FastMap::default(),
            vertex_faces: Vec::new(),
        }
    }

    fn run(mut self) -> OffsetResult {
        let vf = Topology::vertex_faces(self.m);
        self.vertex_faces = vf.clone();
        let mut split = 0;
        for (v, around) in vf.iter().enumerate() {
            if around.is_empty() {
                continue;
            }
            let before = self.clusters.len();
            for fan in self.fans(v as u32, around) {
                self.cluster_fan(v as u32, &fan);
            }
            if self.clusters.len() - before > 1 {
                split += 1;
            }
        }
        for (c, cl) in self.clusters.iter().enumerate() {
            let v = self.cluster_vertex[c];
            self.cluster_point.push(self.out_vertices.len() as u32);
            self.out_vertices.push(self.m.vertices[v as usize] + cl.w);
            self.point_vertex.push(v);
        }
        let mut faces: Vec<[u32; 3]> = Vec::with_capacity(self.m.faces.len() * 2);
        for f in 0..self.m.faces.len() {
            let c = self.corner_cluster[f];
            faces.push([
                self.cluster_point[c[0] as usize],
                self.cluster_point[c[1] as usize],
                self.cluster_point[c[2] as usize],
            ]);
        }
        let moved = faces.len();
        // edge blends
        for ei in 0..self.topo.edges.len() {
            let e = self.topo.edges[ei];
            let (f, g) = (e.faces[0] as usize, e.faces[1] as usize);
            // f runs u→v
            let (f, g) = if Topology::runs_forward(self.m, f, &e) {
                (f, g)
            } else {
                (g, f)
            };
            let (u, v) = (e.v[0], e.v[1]);
            let (fu, gu) = (self.cluster_at(f, u), self.cluster_at(g, u));
            let (fv, gv) = (self.cluster_at(f, v), self.cluster_at(g, v));
            if fu == gu && fv == gv {
                continue;
            }
            // about the edge when it is sharp, else about the sharp edge that split the
            // same two clusters at that end (or about the vertex)
            let convex = edge_kind(self.m, f, g, self.normals[f], self.normals[g]) == Kind::Convex;
            let dir = (self.m.vertices[v as usize] - self.m.vertices[u as usize]).unit();
            let axis_at = |a: u32, b: u32| {
                if convex {
                    dir
                } else {
                    self.pair_axis
                        .get(&(a.min(b), a.max(b)))
                        .copied()
                        .unwrap_or(V3::ZERO)
                }
            };
            let (au, av) = (axis_at(fu, gu), axis_at(fv, gv));
            let us = self.arc(u, fu, gu, au);
            let vs = self.arc(v, fv, gv, av);
            zipper(&us, &vs, &mut faces);
        }
        let edge_blends = faces.len() - moved;
        // corner holes: the edges used once, grouped by their vertex of origin
        let corner_start = faces.len();
        self.fill_corners(&mut faces);
        let corner_blends = faces.len() - corner_start;
        let mesh = Mesh::new("offset", self.out_vertices, faces);
        OffsetResult {
            report: OffsetReport {
                faces_in: self.m.faces.len(),
                faces_out: mesh.faces.len(),
                moved_faces: moved,
                edge_blend_faces: edge_blends,
                corner_blend_faces: corner_blends,
                split_vertices: split,
                method: OffsetMethod::MultipleNormals,
                grid_step: 0.0,
                worst_error: 0.0,
            },
            mesh,
        }
    }

    fn cluster_at(&self, f: usize, v: u32) -> u32 {
        let face = self.m.faces[f];
        let k = face
            .iter()
            .position(|&x| x == v)
            .expect("the face holds the vertex");
        self.corner_cluster[f][k]
    }

    /// The faces round `v` in order, one list per fan (more than one at a vertex where
    /// two sheets touch).
    fn fans(&self, v: u32, faces: &[u32]) -> Vec<Vec<u32>> {
        let mut seen: FastMap<u32, bool> = FastMap::default();
        let mut fans = Vec::new();
        for &start in faces {
            if seen.contains_key(&start) {
                continue;
            }
            let mut fan = Vec::new();
            let mut f = start;
            loop {
                seen.insert(f, true);
                fan.push(f);
                // across the edge from the corner before v to v
                let face = self.m.faces[f as usize];
                let k = face.iter().position(|&x| x == v).unwrap();
                let ei = self.topo.face_edges[f as usize][(k + 2) % 3];
                match self.topo.across(ei, f) {
                    Some(g) if g != start && !seen.contains_key(&g) => f = g,
                    _ => break,
                }
            }
            fans.push(fan);
        }
        fans
    }

    /// Clusters the normals of one fan round `v` and records each face's cluster there.
    ///
    /// Clusters are runs of the ring between cuts. Every convex edge starts as a cut;
    /// then the cut between the two clusters with the closest mean normals goes while the
    /// merged cluster stays within the tolerance. A ring left with one cut whose edge is
    /// too sharp to share a point (a convex edge ending where its faces also meet a
    /// concave one, as a boss's side edge at its foot) gets a second cut across a flat
    /// edge, so that each side keeps its own point and the trim arc between them lies on
    /// the flat.
    fn cluster_fan(&mut self, v: u32, fan: &[u32]) {
        let n = fan.len();
        let p = self.m.vertices[v as usize];
        let tris: Vec<[V3; 3]> = fan.iter().map(|&f| self.m.triangle(f as usize)).collect();
        let weights: Vec<f64> = fan
            .iter()
            .map(|&f| {
                let face = self.m.faces[f as usize];
                let k = face.iter().position(|&x| x == v).unwrap();
                let a = self.m.vertices[face[(k + 1) % 3] as usize] - p;
                let b = self.m.vertices[face[(k + 2) % 3] as usize] - p;
                a.cross(b).len().atan2(a.dot(b)).max(1e-12)
            })
            .collect();
        let normals: Vec<V3> = fan.iter().map(|&f| self.normals[f as usize]).collect();
        // the edge between fan[i] and fan[i+1]: its far end, and its kind
        let other: Vec<Option<u32>> = (0..n)
            .map(|i| {
                let (f, g) = (fan[i], fan[(i + 1) % n]);
                let (ff, gf) = (self.m.faces[f as usize], self.m.faces[g as usize]);
                ff.iter().copied().find(|&x| x != v && gf.contains(&x))
            })
            .collect();
        let kind: Vec<Kind> = (0..n)
            .map(|i| {
                if n == 1 {
                    return Kind::Flat;
                }
                edge_kind(
                    self.m,
                    fan[i] as usize,
                    fan[(i + 1) % n] as usize,
                    normals[i],
                    normals[(i + 1) % n],
                )
            })
            .collect();
        let solve = |members: &[usize]| -> (V3, f64) {
            let w = least_squares(members.iter().map(|&i| (normals[i], weights[i])), self.d);
            let plane = members
                .iter()
                .map(|&i| (normals[i].dot(w) - self.d).abs())
                .fold(0.0, f64::max);
            let q = p + w;
            let near = tris
                .iter()
                .map(|t| dist_to_triangle(q, t))
                .fold(f64::INFINITY, f64::min);
            let mut err = plane.max((near - self.d).abs());
            // a convex edge inside the cluster: the point's distance from its line
            for &i in members {
                if kind[i] == Kind::Convex && n > 1 && members.contains(&((i + 1) % n)) {
                    if let Some(o) = other[i] {
                        let e = (self.m.vertices[o as usize] - p).unit();
                        let off = w - e * w.dot(e);
                        err = err.max(off.len() - self.d);
                    }
                }
            }
            (w, err)
        };
        // runs of the ring between cuts: cut[i] separates fan[i] and fan[i+1]
        let runs = |cut: &[bool]| -> Vec<Vec<usize>> {
            let cuts: Vec<usize> = (0..n).filter(|&i| cut[i]).collect();
            if cuts.len() <= 1 {
                let s = cuts.first().map(|&c| (c + 1) % n).unwrap_or(0);
                return vec![(0..n).map(|k| (s + k) % n).collect()];
            }
            (0..cuts.len())
                .map(|k| {
                    let (a, b) = (cuts[k], cuts[(k + 1) % cuts.len()]);
                    let len = (b + n - a) % n;
                    (1..=len).map(|j| (a + j) % n).collect()
                })
                .collect()
        };
        let mean = |members: &[usize]| {
            members
                .iter()
                .fold(V3::ZERO, |s, &i| s + normals[i] * weights[i])
                .unit()
        };
        let mut cut: Vec<bool> = kind.iter().map(|&k| k == Kind::Convex).collect();
        let mut refused = vec![false; n];
        loop {
            let rs = runs(&cut);
            if rs.len() <= 1 {
                break;
            }
            // the cut between the closest mean normals that may go
            let mut best: Option<(f64, usize)> = None;
            for (k, r) in rs.iter().enumerate() {
                let c = *r.last().unwrap(); // the cut after run k
                if !cut[c] || refused[c] {
                    continue;
                }
                let next = &rs[(k + 1) % rs.len()];
                let cos = mean(r).dot(mean(next));
                if best.is_none_or(|(b, _)| cos > b) {
                    best = Some((cos, c));
                }
            }
            let Some((_, c)) = best else { break };
            let mut trial = cut.clone();
            trial[c] = false;
            let merged = runs(&trial)
                .into_iter()
                .find(|r| r.contains(&c))
                .unwrap_or_default();
            if solve(&merged).1 <= self.tol {
                cut = trial;
                refused.iter_mut().for_each(|r| *r = false);
            } else {
                refused[c] = true;
            }
        }
        let cuts: Vec<usize> = (0..n).filter(|&i| cut[i]).collect();
        if cuts.len() == 1 && solve(&runs(&cut)[0]).1 > self.tol {
            // one sharp edge in a ring that otherwise bends the other way or lies flat:
            // cut across a flat edge between the faces that turn most from the sharp
            // edge's two (the flat the trim arc lies on), the farthest round the ring
            let c = cuts[0];
            let (na, nb) = (normals[c], normals[(c + 1) % n]);
            let turn = |i: usize| {
                let m = normals[i];
                (1.0 - m.dot(na)).min(1.0 - m.dot(nb))
            };
            let far = (0..n)
                .filter(|&i| kind[i] == Kind::Flat && turn(i) > 1e-6)
                .max_by(|&i, &j| {
                    let ring = |i: usize| {
                        let k = (i + n - c) % n;
                        k.min(n - k)
                    };
                    turn(i).total_cmp(&turn(j)).then(ring(i).cmp(&ring(j)))
                });
            if let Some(f) = far {
                cut[f] = true;
            }
        }
        // record the clusters, and for each pair split by a convex cut the cut's axis
        let rs = runs(&cut);
        let base = self.clusters.len() as u32;
        let mut run_of = vec![0u32; n];
        for (k, r) in rs.iter().enumerate() {
            let (w, _) = solve(r);
            self.clusters.push(Cluster { w });
            self.cluster_vertex.push(v);
            for &i in r {
                run_of[i] = base + k as u32;
                let f = fan[i] as usize;
                let kk = self.m.faces[f].iter().position(|&x| x == v).unwrap();
                self.corner_cluster[f][kk] = base + k as u32;
            }
        }
        for i in 0..n {
            if cut[i] && kind[i] == Kind::Convex && rs.len() > 1 {
                if let Some(o) = other[i] {
                    let (a, b) = (run_of[i], run_of[(i + 1) % n]);
                    let axis = (self.m.vertices[o as usize] - p).unit();
                    self.pair_axis.entry((a.min(b), a.max(b))).or_insert(axis);
                }
            }
        }
    }

    /// The output points turning from cluster `a`'s point to `b`'s about vertex `v`
    /// (both ends included; one point when a = b), about `axis` (the sharp edge's line
    /// through v; zero: about the vertex), made once per pair and axis.
    fn arc(&mut self, v: u32, a: u32, b: u32, axis: V3) -> Vec<u32> {
        if a == b {
            return vec![self.cluster_point[a as usize]];
        }
        let (lo, hi) = (a.min(b), a.max(b));
        let same = |x: V3| (x == V3::ZERO && axis == V3::ZERO) || x.dot(axis).abs() > 1.0 - 1e-12;
        if let Some(list) = self.arcs.get(&(lo, hi)) {
            if let Some((_, pts)) = list.iter().find(|(x, _)| same(*x)) {
                let mut pts = pts.clone();
                if a != lo {
                    pts.reverse();
                }
                return pts;
            }
        }
        let pts = self.arc_points(v, lo, hi, axis);
        // an arc made about another sharp edge through the vertex that strays no more
        // than a quarter of the tolerance from this one serves both (a curved sharp edge
        // then leaves no sliver of a hole between two nearly equal arcs)
        if let Some(list) = self.arcs.get(&(lo, hi)) {
            for (_, other) in list {
                if other.len() == pts.len() + 2
                    && pts
                        .iter()
                        .zip(&other[1..])
                        .all(|(p, &o)| p.dist(self.out_vertices[o as usize]) <= 0.25 * self.tol)
                {
                    let mut shared = other.clone();
                    if a != lo {
                        shared.reverse();
                    }
                    return shared;
                }
            }
        }
        let mut idx = vec![self.cluster_point[lo as usize]];
        for q in pts {
            idx.push(self.out_vertices.len() as u32);
            self.out_vertices.push(q);
            self.point_vertex.push(v);
        }
        idx.push(self.cluster_point[hi as usize]);
        self.arcs
            .entry((lo, hi))
            .or_default()
            .push((axis, idx.clone()));
        if a != lo {
            idx.reverse();
        }
        idx
    }

    /// The inner points of the arc from cluster `lo`'s point to `hi`'s about `axis`.
    fn arc_points(&self, v: u32, lo: u32, hi: u32, axis: V3) -> Vec<V3> {
        let c = self.m.vertices[v as usize];
        let (wa, wb) = (self.clusters[lo as usize].w, self.clusters[hi as usize].w);
        let (along_a, along_b) = (axis * wa.dot(axis), axis * wb.dot(axis));
        let (pa, pb) = (wa - along_a, wb - along_b);
        let steps = self.steps(pa, pb);
        // the parts along the axis: equal ones stay (the arc trims a flat both clusters
        // share, as at a boss's foot grown out); unequal ones follow the turn's own weights
        // (an arc ending on a corner point off the edge's foot stays in the plane that
        // bisects the two edges there, as at a boss's foot shrunk in)
        let ang = pa.unit().dot(pb.unit()).clamp(-1.0, 1.0).acos();
        let same_along = along_a.dist(along_b) <= 1e-9 * (1.0 + wa.len());
        (1..steps)
            .map(|s| {
                let t = s as f64 / steps as f64;
                let (ka, kb) = if ang > 1e-9 && !same_along {
                    (
                        ((1.0 - t) * ang).sin() / ang.sin(),
                        (t * ang).sin() / ang.sin(),
                    )
                } else {
                    (1.0 - t, t)
                };
                c + along_a * ka + along_b * kb + slerp(pa, pb, t)
            })
            .collect()
    }

    /// Steps for turning from `wa` to `wb` with each chord's sagitta within a quarter of the
    /// tolerance.
    fn steps(&self, wa: V3, wb: V3) -> usize {
        let ang = wa.unit().dot(wb.unit()).clamp(-1.0, 1.0).acos();
        let r = wa.len().max(wb.len());
        let sag = (0.25 * self.tol).min(r);
        let max_step = 2.0 * (1.0 - sag / r).clamp(-1.0, 1.0).acos();
        ((ang / max_step.max(1e-6)).ceil() as usize).clamp(1, 10_000)
    }

    fn fill_corners(&mut self, faces: &mut Vec<[u32; 3]>) {
        // directed edges used once (their reverse unused)
        let mut used: FastMap<(u32, u32), i32> = FastMap::default();
        for f in faces.iter() {
            for k in 0..3 {
                let (a, b) = (f[k], f[(k + 1) % 3]);
                if a == b {
                    continue;
                }
                *used.entry((a, b)).or_insert(0) += 1;
            }
        }
        let mut open: FastMap<u32, Vec<u32>> = FastMap::default();
        let mut keys: Vec<(u32, u32)> = used
            .iter()
            .filter(|(&(a, b), &n)| n == 1 && !used.contains_key(&(b, a)))
            .map(|(&k, _)| k)
            .collect();
        keys.sort_unstable();
        for (a, b) in keys {
            open.entry(a).or_default().push(b);
        }
        let mut starts: Vec<u32> = open.keys().copied().collect();
        starts.sort_unstable();
        for s in starts {
            while let Some(first) = open.get_mut(&s).and_then(|l| l.pop()) {
                // walk a loop of boundary edges s → first → …
                let mut lp = vec![s];
                let mut at = first;
                let mut guard = 0;
                while at != s && guard < 1_000_000 {
                    lp.push(at);
                    match open.get_mut(&at).and_then(|l| l.pop()) {
                        Some(n) => at = n,
                        None => break,
                    }
                    guard += 1;
                }
                if at == s && lp.len() >= 3 {
                    self.fill_hole(&lp, faces);
                }
            }
        }
    }

    /// Fills the hole bounded by `lp` (its edges lp[i] → lp[i+1] already used by faces)
    /// with a fan about the vertex the points came from, split to the tolerance; the inner
    /// points are set along their directions at the offset distance from the vertex's
    /// faces (on a sphere about a convex corner that is the sphere; where the corner also
    /// bends the other way, the trimmed surface between the blends).
    fn fill_hole(&mut self, lp: &[u32], faces: &mut Vec<[u32; 3]>) {
        let v = self.point_vertex[lp[0] as usize];
        let c = self.m.vertices[v as usize];
        let ring: Vec<[V3; 3]> = self.vertex_faces[v as usize]
            .iter()
            .map(|&f| self.m.triangle(f as usize))
            .collect();
        let (d, tol) = (self.d, self.tol);
        let place = |dir: V3, guess: f64| -> V3 {
            // the length along `dir` at which the point is d from the ring (the distance
            // grows with the length for directions out of the solid)
            let dist = |r: f64| {
                ring.iter()
                    .map(|t| dist_to_triangle(c + dir * r, t))
                    .fold(f64::INFINITY, f64::min)
            };
            if (dist(guess) - d).abs() <= 1e-3 * tol {
                return dir * guess; // on the sphere of a convex corner already
            }
            let (mut lo, mut hi) = (0.0, guess.max(d) * 2.0);
            if dist(hi) < d {
                return dir * guess;
            }
            for _ in 0..40 {
                let mid = 0.5 * (lo + hi);
                if dist(mid) < d {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            dir * (0.5 * (lo + hi))
        };
        let dirs: Vec<V3> = lp
            .iter()
            .map(|&i| self.out_vertices[i as usize] - c)
            .collect();
        let mut mid = dirs.iter().fold(V3::ZERO, |s, &w| s + w.unit());
        if mid.len() < 1e-9 {
            mid = dirs[0];
        }
        let mean_len = dirs.iter().map(|w| w.len()).sum::<f64>() / dirs.len() as f64;
        let centre_w = place(mid.unit(), mean_len);
        let s = dirs
            .iter()
            .map(|&w| self.steps(centre_w, w))
            .max()
            .unwrap_or(1);
        let centre = self.out_vertices.len() as u32;
        self.out_vertices.push(c + centre_w);
        self.point_vertex.push(v);
        // spokes: centre → each loop point in s steps
        let spokes: Vec<Vec<u32>> = lp
            .iter()
            .zip(&dirs)
            .map(|(&end, &w)| {
                let mut sp = vec![centre];
                for j in 1..s {
                    let q = slerp(centre_w, w, j as f64 / s as f64);
                    sp.push(self.out_vertices.len() as u32);
                    self.out_vertices.push(c + place(q.unit(), q.len()));
                    self.point_vertex.push(v);
                }
                sp.push(end);
                sp
            })
            .collect();
        let n = lp.len();
        for i in 0..n {
            // boundary edge lp[i] → lp[i+1] is used: the fill runs lp[i+1] → lp[i]
            let (a, b) = (&spokes[i], &spokes[(i + 1) % n]);
            faces.push([centre, b[1], a[1]]);
            for j in 1..s {
                faces.push([b[j], b[j + 1], a[j + 1]]);
                faces.push([b[j], a[j + 1], a[j]]);
            }
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Convex,
    Flat,
    Concave,
}

/// Whether the edge between faces `f` and `g` (normals `nf`, `ng`) is convex (the faces
/// fold away from their normals), concave, or flat.
fn edge_kind(m: &Mesh, f: usize, g: usize, nf: V3, ng: V3) -> Kind {
    if nf.dot(ng) > 1.0 - 1e-12 {
        return Kind::Flat;
    }
    let (ff, gf) = (m.faces[f], m.faces[g]);
    let Some(o) = gf.iter().copied().find(|x| !ff.contains(x)) else {
        return Kind::Flat;
    };
    let on = ff.iter().copied().find(|x| gf.contains(x)).unwrap_or(ff[0]);
    let q = m.vertices[o as usize] - m.vertices[on as usize];
    let s = nf.dot(q);
    if s < -1e-12 * q.len() {
        Kind::Convex
    } else if s > 1e-12 * q.len() {
        Kind::Concave
    } else {
        Kind::Flat
    }
}

/// Blend faces between the arc `us` at an edge's first end (from the first face's point
/// to the second's) and the arc `vs` at its other end (likewise).
fn zipper(us: &[u32], vs: &[u32], faces: &mut Vec<[u32; 3]>) {
    let (m, n) = (us.len() - 1, vs.len() - 1);
    let (mut i, mut j) = (0, 0);
    while i < m || j < n {
        let advance_u = if i == m {
            false
        } else if j == n {
            true
        } else {
            (i + 1) as f64 / m as f64 <= (j + 1) as f64 / n as f64
        };
        if advance_u {
            faces.push([vs[j], us[i], us[i + 1]]);
            i += 1;
        } else {
            faces.push([vs[j], us[i], vs[j + 1]]);
            j += 1;
        }
    }
}

/// Turns from `a` to `b` by `t`: direction on the great circle, length linearly.
fn slerp(a: V3, b: V3, t: f64) -> V3 {
    let (la, lb) = (a.len(), b.len());
    let (ua, ub) = (a / la, b / lb);
    let cos = ua.dot(ub).clamp(-1.0, 1.0);
    let ang = cos.acos();
    let dir = if ang < 1e-9 {
        ua.lerp(ub, t).unit()
    } else {
        let s = ang.sin();
        (ua * (((1.0 - t) * ang).sin() / s) + ub * ((t * ang).sin() / s)).unit()
    };
    dir * (la + (lb - la) * t)
}

/// The w that best satisfies n·w = d for the weighted normals (pseudo-inverse of the
/// normal equations: directions the normals do not constrain get no component).
fn least_squares(normals: impl Iterator<Item = (V3, f64)>, d: f64) -> V3 {
    let mut a = [[0.0f64; 3]; 3];
    let mut rhs = V3::ZERO;
    for (n, w) in normals {
        let v = [n.x, n.y, n.z];
        for r in 0..3 {
            for c in 0..3 {
                a[r][c] += w * v[r] * v[c];
            }
        }
        rhs += n * (w * d);
    }
    let (vals, vecs) = jacobi3(a);
    let top = vals.iter().copied().fold(0.0, f64::max);
    let mut w = V3::ZERO;
    for k in 0..3 {
        if vals[k] > 1e-4 * top {
            let e = V3::new(vecs[0][k], vecs[1][k], vecs[2][k]);
            w += e * (e.dot(rhs) / vals[k]);
        }
    }
    w
}

/// Eigenvalues and eigenvectors (columns) of a symmetric 3×3 matrix, by Jacobi rotations.
#[allow(clippy::needless_range_loop)] // index arithmetic reads as the textbook's
fn jacobi3(mut a: [[f64; 3]; 3]) -> ([f64; 3], [[f64; 3]; 3]) {
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for _ in 0..32 {
        let off = a[0][1].abs() + a[0][2].abs() + a[1][2].abs();
        if off < 1e-300 {
            break;
        }
        for (p, q) in [(0usize, 1usize), (0, 2), (1, 2)] {
            if a[p][q].abs() < 1e-300 {
                continue;
            }
            let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let t = if theta == 0.0 { 1.0 } else { t };
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            // A' = Jᵀ A J with J the rotation in the (p, q) plane
            for k in 0..3 {
                let (akp, akq) = (a[k][p], a[k][q]);
                a[k][p] = c * akp - s * akq;
                a[k][q] = s * akp + c * akq;
            }
            for k in 0..3 {
                let (apk, aqk) = (a[p][k], a[q][k]);
                a[p][k] = c * apk - s * aqk;
                a[q][k] = s * apk + c * aqk;
            }
            for row in v.iter_mut() {
                let (vkp, vkq) = (row[p], row[q]);
                row[p] = c * vkp - s * vkq;
                row[q] = s * vkp + c * vkq;
            }
        }
    }
    ([a[0][0], a[1][1], a[2][2]], v)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::shapes::cuboid;

    #[test]
    fn least_squares_meets_three_planes_and_one() {
        let w = least_squares(
            [
                (V3::new(1.0, 0.0, 0.0), 1.0),
                (V3::new(0.0, 1.0, 0.0), 2.0),
                (V3::new(0.0, 0.0, 1.0), 0.5),
            ]
            .into_iter(),
            2.0,
        );
        assert!(w.dist(V3::new(2.0, 2.0, 2.0)) < 1e-12, "{w:?}");
        let w = least_squares([(V3::new(0.0, 0.6, 0.8), 1.0)].into_iter(), 2.0);
        assert!(w.dist(V3::new(0.0, 1.2, 1.6)) < 1e-12, "{w:?}");
    }

    #[test]
    fn a_grown_box_is_closed_and_rounded() {
        let m = cuboid(V3::ZERO, V3::new(10.0, 8.0, 6.0));
        let r = offset(&m, 1.0, &MeshOffsetOptions { tolerance: 0.01 }).unwrap();
        let rep = r.mesh.report();
        assert!(rep.closed, "{rep:?}");
        let (err, _) = measure_error(&m, &r.mesh, 1.0, 3);
        assert!(err <= 0.01, "worst error {err}");
        assert_eq!(r.report.split_vertices, 8);
        // volume of the rounded box: V + A d + (edges) π d²/4 + 4/3 π d³
        let want = 480.0
            + 2.0 * (80.0 + 60.0 + 48.0)
            + std::f64::consts::PI * 24.0 / 4.0 * 4.0 / 1.0 * 1.0
            + 4.0 / 3.0 * std::f64::consts::PI;
        assert!(
            (r.mesh.volume() - want).abs() < 0.5,
            "volume {} vs {want}",
            r.mesh.volume()
        );
    }

    #[test]
    fn a_shrunk_box_is_the_smaller_box() {
        let m = cuboid(V3::ZERO, V3::new(10.0, 8.0, 6.0));
        let r = offset(&m, -1.0, &MeshOffsetOptions { tolerance: 0.01 }).unwrap();
        assert!(r.mesh.report().closed);
        assert!(
            (r.mesh.volume() - 8.0 * 6.0 * 4.0).abs() < 1e-9,
            "{}",
            r.mesh.volume()
        );
    }
}
