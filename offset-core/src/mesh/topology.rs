//! Mesh topology: welding vertices, the edges and which faces share them, and the defects
//! a solid must not have (non-manifold edges, holes, flipped faces), reported by face.

use super::FastMap;
use super::{Mesh, V3};

/// Welds points closer than a tolerance into one vertex, through a hash grid of cells the
/// size of the tolerance (a point's twin lies in one of the 27 cells around it).
pub struct Welder {
    tol: f64,
    cells: FastMap<(i64, i64, i64), Vec<u32>>,
    vertices: Vec<V3>,
}

impl Welder {
    pub fn new(tol: f64) -> Self {
        Welder {
            tol: if tol > 0.0 { tol } else { 1e-12 },
            cells: FastMap::default(),
            vertices: Vec::new(),
        }
    }

    fn cell(&self, p: V3) -> (i64, i64, i64) {
        let k = |v: f64| (v / self.tol).floor() as i64;
        (k(p.x), k(p.y), k(p.z))
    }

    /// The index of the vertex at `p` (an existing one within the tolerance, or a new one).
    pub fn add(&mut self, p: V3) -> u32 {
        let (cx, cy, cz) = self.cell(p);
        let mut best: Option<(u32, f64)> = None;
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    if let Some(list) = self.cells.get(&(cx + dx, cy + dy, cz + dz)) {
                        for &i in list {
                            let d = self.vertices[i as usize].dist(p);
                            if d <= self.tol && best.is_none_or(|(_, bd)| d < bd) {
                                best = Some((i, d));
                            }
                        }
                    }
                }
            }
        }
        if let Some((i, _)) = best {
            return i;
        }
        let i = self.vertices.len() as u32;
        self.vertices.push(p);
        self.cells.entry((cx, cy, cz)).or_default().push(i);
        i
    }

    pub fn into_vertices(self) -> Vec<V3> {
        self.vertices
    }
}

/// One undirected edge: its vertices (lower index first), the first two faces that use it
/// and how many do.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Edge {
    pub v: [u32; 2],
    pub faces: [u32; 2],
    pub count: u32,
}

/// The edges of a mesh and, for each face, the edge of each side (side k runs from corner
/// k to corner k+1).
#[derive(Clone, Debug, Default)]
pub struct Topology {
    pub edges: Vec<Edge>,
    pub face_edges: Vec<[u32; 3]>,
}

/// What a mesh is made of and what is wrong with it as a solid.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MeshReport {
    pub faces: usize,
    pub vertices: usize,
    pub edges: usize,
    /// Edges used by one face only (the rims of holes).
    pub boundary_edges: usize,
    /// The faces along those edges.
    pub boundary_faces: Vec<usize>,
    /// Edges used by more than two faces.
    pub non_manifold_edges: usize,
    /// The faces along those edges.
    pub non_manifold_faces: Vec<usize>,
    /// Faces that turn the other way from their neighbours (the smaller side of each
    /// inconsistency).
    pub flipped_faces: Vec<usize>,
    /// Every edge shared by exactly two faces turning opposite ways along it.
    pub closed: bool,
}

impl MeshReport {
    /// What keeps the mesh from being a closed solid, in one line ("open: 72 boundary
    /// edges; 3 non-manifold edges"), or None for a closed solid.
    pub fn defects(&self) -> Option<String> {
        let mut parts = Vec::new();
        if self.boundary_edges > 0 {
            parts.push(format!("{} boundary edges", self.boundary_edges));
        }
        if self.non_manifold_edges > 0 {
            parts.push(format!("{} non-manifold edges", self.non_manifold_edges));
        }
        if !self.flipped_faces.is_empty() {
            parts.push(format!(
                "{} faces turned against their neighbours",
                self.flipped_faces.len()
            ));
        }
        if parts.is_empty() {
            return None;
        }
        let kind = if self.boundary_edges > 0 {
            "open"
        } else {
            "not a closed solid"
        };
        Some(format!("{kind}: {}", parts.join("; ")))
    }
}

impl Topology {
    pub fn new(m: &Mesh) -> Topology {
        let mut sides: Vec<(u32, u32, u32, u8)> = Vec::with_capacity(m.faces.len() * 3);
        for (f, face) in m.faces.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (face[k], face[(k + 1) % 3]);
                sides.push((a.min(b), a.max(b), f as u32, k as u8));
            }
        }
        sides.sort_unstable();
        let mut edges: Vec<Edge> = Vec::with_capacity(sides.len() / 2 + 1);
        let mut face_edges = vec![[u32::MAX; 3]; m.faces.len()];
        let mut i = 0;
        while i < sides.len() {
            let (a, b, _, _) = sides[i];
            let mut j = i;
            let mut e = Edge {
                v: [a, b],
                faces: [u32::MAX; 2],
                count: 0,
            };
            while j < sides.len() && sides[j].0 == a && sides[j].1 == b {
                let (_, _, f, k) = sides[j];
                if (e.count as usize) < 2 {
                    e.faces[e.count as usize] = f;
                }
                e.count += 1;
                face_edges[f as usize][k as usize] = edges.len() as u32;
                j += 1;
            }
            edges.push(e);
            i = j;
        }
        Topology { edges, face_edges }
    }

    /// All faces that use edge `e`.
    pub fn faces_of_edge(&self, m: &Mesh, e: &Edge) -> Vec<usize> {
        let idx = self
            .edges
            .iter()
            .position(|x| x == e)
            .map(|i| i as u32)
            .unwrap_or(u32::MAX);
        (0..m.faces.len())
            .filter(|&f| self.face_edges[f].contains(&idx))
            .collect()
    }

    /// Whether face `f` runs along edge `e` from its first vertex to its second.
    pub fn runs_forward(m: &Mesh, f: usize, e: &Edge) -> bool {
        let face = m.faces[f];
        (0..3).any(|k| face[k] == e.v[0] && face[(k + 1) % 3] == e.v[1])
    }

    /// The face across edge `e` from face `f` (None on a boundary or non-manifold edge).
    pub fn across(&self, e: u32, f: u32) -> Option<u32> {
        let e = &self.edges[e as usize];
        if e.count != 2 {
            return None;
        }
        Some(if e.faces[0] == f {
            e.faces[1]
        } else {
            e.faces[0]
        })
    }

    /// The defects of the mesh as a solid.
    pub fn report(&self, m: &Mesh) -> MeshReport {
        let mut r = MeshReport {
            faces: m.faces.len(),
            vertices: {
                let mut used = vec![false; m.vertices.len()];
                for f in &m.faces {
                    for &v in f {
                        used[v as usize] = true;
                    }
                }
                used.iter().filter(|&&u| u).count()
            },
            edges: self.edges.len(),
            ..Default::default()
        };
        let mut on_boundary = vec![false; m.faces.len()];
        for e in &self.edges {
            if e.count == 1 {
                r.boundary_edges += 1;
                on_boundary[e.faces[0] as usize] = true;
            } else if e.count > 2 {
                r.non_manifold_edges += 1;
            }
        }
        r.boundary_faces = (0..m.faces.len()).filter(|&f| on_boundary[f]).collect();
        // one pass over the faces (not one per non-manifold edge: a scanned mesh has many)
        r.non_manifold_faces = (0..m.faces.len())
            .filter(|&f| {
                self.face_edges[f]
                    .iter()
                    .any(|&e| self.edges.get(e as usize).is_some_and(|e| e.count > 2))
            })
            .collect();
        r.flipped_faces = self.flipped(m);
        r.closed = r.boundary_edges == 0 && r.non_manifold_edges == 0 && r.flipped_faces.is_empty();
        r
    }

    /// Faces whose orientation disagrees with their neighbours': per connected piece, the
    /// orientation spreads from one face across the two-face edges, and the faces that had
    /// to be turned over are reported (or the others, when they are fewer), plus any face
    /// where the spread met itself turned (a one-sided surface).
    fn flipped(&self, m: &Mesh) -> Vec<usize> {
        let n = m.faces.len();
        let mut sign = vec![0i8; n];
        let mut out = Vec::new();
        let mut stack = Vec::new();
        for seed in 0..n {
            if sign[seed] != 0 {
                continue;
            }
            sign[seed] = 1;
            stack.push(seed);
            let mut piece = vec![seed];
            let mut conflicts = Vec::new();
            while let Some(f) = stack.pop() {
                for &ei in &self.face_edges[f] {
                    let e = &self.edges[ei as usize];
                    let Some(g) = self.across(ei, f as u32) else {
                        continue;
                    };
                    let g = g as usize;
                    let same_way = Self::runs_forward(m, f, e) == Self::runs_forward(m, g, e);
                    let want = if same_way { -sign[f] } else { sign[f] };
                    if sign[g] == 0 {
                        sign[g] = want;
                        piece.push(g);
                        stack.push(g);
                    } else if sign[g] != want {
                        conflicts.push(g);
                    }
                }
            }
            let minus: Vec<usize> = piece.iter().copied().filter(|&f| sign[f] < 0).collect();
            if minus.len() * 2 <= piece.len() {
                out.extend(minus);
            } else {
                out.extend(piece.iter().copied().filter(|&f| sign[f] > 0));
            }
            out.extend(conflicts);
        }
        out.sort_unstable();
        out.dedup();
        out
    }

    /// The faces around each vertex.
    pub fn vertex_faces(m: &Mesh) -> Vec<Vec<u32>> {
        let mut vf = vec![Vec::new(); m.vertices.len()];
        for (f, face) in m.faces.iter().enumerate() {
            for &v in face {
                vf[v as usize].push(f as u32);
            }
        }
        vf
    }
}

impl Mesh {
    /// The mesh's topology and its defects as a solid.
    pub fn report(&self) -> MeshReport {
        Topology::new(self).report(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tetra() -> Mesh {
        Mesh::new(
            "tetra",
            vec![
                V3::new(0.0, 0.0, 0.0),
                V3::new(1.0, 0.0, 0.0),
                V3::new(0.0, 1.0, 0.0),
                V3::new(0.0, 0.0, 1.0),
            ],
            vec![[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]],
        )
    }

    #[test]
    fn a_tetrahedron_is_closed_with_six_edges() {
        let m = tetra();
        let r = m.report();
        assert_eq!((r.edges, r.boundary_edges, r.non_manifold_edges), (6, 0, 0));
        assert!(r.closed && r.flipped_faces.is_empty(), "{r:?}");
        assert!((m.volume() - 1.0 / 6.0).abs() < 1e-12);
    }

    #[test]
    fn a_flipped_face_is_named() {
        let mut m = tetra();
        m.faces[2] = [1, 3, 2];
        let r = m.report();
        assert_eq!(r.flipped_faces, vec![2]);
        assert!(!r.closed);
    }

    #[test]
    fn a_missing_face_leaves_three_boundary_edges() {
        let mut m = tetra();
        m.faces.pop();
        let r = m.report();
        assert_eq!(r.boundary_edges, 3);
        assert_eq!(r.boundary_faces, vec![0, 1, 2]);
    }

    #[test]
    fn welding_merges_points_within_the_tolerance() {
        let mut w = Welder::new(1e-3);
        let a = w.add(V3::new(1.0, 1.0, 1.0));
        let b = w.add(V3::new(1.0004, 0.9996, 1.0));
        let c = w.add(V3::new(1.002, 1.0, 1.0));
        assert_eq!(a, b);
        assert_ne!(a, c);
    }
}
