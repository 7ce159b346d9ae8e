//! Triangle meshes (STL parts, surfaces fitted to measured points) and the 3D work on
//! them: offsets by multiple normals, z-level slices for roughing, drop-cutter and
//! waterline finishing (docs/3d.md).
//!
//! Meshes are machined in their own frame: the STL's coordinates are the work coordinates
//! and the stock top defaults to the mesh's highest Z (DESIGN.md, Geometry).

pub mod bvh;
pub mod dropcutter;
pub mod envelope;
pub mod finish;
pub mod offset;
pub mod offset_field;
pub mod rough;
pub mod shapes;
pub mod slice;
pub mod stl;
pub mod surface;
pub mod topology;
pub mod v3;
pub mod waterline;

pub use dropcutter::{Cutter, CutterShape, DropCutter};
pub use finish::{finish3d, Finish3dParams};
pub use offset::{
    measure_error, offset, MeshOffsetOptions, OffsetMethod, OffsetReport, OffsetResult,
};
pub use rough::{rough3d, rough3d_safe_links, Rough3dParams};
pub use slice::slice_at;
pub use stl::{read_stl, write_stl};
pub use surface::{mesh_from_points, read_point_grid, BicubicSurface, PointGrid};
pub use topology::{MeshReport, Topology};
pub use v3::V3;
pub use waterline::{waterline3d, WaterlineParams};

use crate::ops::OpError;
use serde::{Deserialize, Serialize};

/// A fast hasher for the integer keys of the mesh code's maps (FxHash: rotate, xor,
/// multiply); the default SipHash would make welding, slicing and offsets several times
/// slower.
#[derive(Default, Clone, Copy)]
pub(crate) struct FxHasher(u64);

impl FxHasher {
    fn add(&mut self, w: u64) {
        self.0 = (self.0.rotate_left(5) ^ w).wrapping_mul(0x517c_c1b7_2722_0a95);
    }
}

impl std::hash::Hasher for FxHasher {
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.add(b as u64);
        }
    }
    fn write_u32(&mut self, i: u32) {
        self.add(i as u64);
    }
    fn write_u64(&mut self, i: u64) {
        self.add(i);
    }
    fn write_i64(&mut self, i: i64) {
        self.add(i as u64);
    }
    fn write_usize(&mut self, i: usize) {
        self.add(i as u64);
    }
    fn finish(&self) -> u64 {
        self.0
    }
}

/// A hash map keyed by integers, with [`FxHasher`].
pub(crate) type FastMap<K, V> =
    std::collections::HashMap<K, V, std::hash::BuildHasherDefault<FxHasher>>;

/// A triangle mesh: shared vertices and faces of three vertex indices, counter-clockwise
/// seen from outside (the right-hand normal points out of the material).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Mesh {
    /// Where the mesh came from (file name), for messages.
    pub name: String,
    pub vertices: Vec<V3>,
    pub faces: Vec<[u32; 3]>,
}

/// How to read a mesh.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct MeshOptions {
    /// Vertices closer than this are welded into one, mm.
    pub weld_tolerance: f64,
    /// The most faces a mesh may have; a bigger one is refused by name (the budget keeps
    /// the daemon's memory and the planning time bounded: 2 000 000 faces take ≈ 150 MB
    /// while planning).
    pub max_faces: usize,
}

/// The default face budget of [`MeshOptions::max_faces`].
pub const MAX_FACES: usize = 2_000_000;

impl Default for MeshOptions {
    fn default() -> Self {
        MeshOptions {
            weld_tolerance: 1e-4,
            max_faces: MAX_FACES,
        }
    }
}

/// Why a mesh could not be read or worked on. Each says in one sentence what was wrong and
/// where (file, face, vertex, line).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MeshError {
    #[error("{name}: {message}")]
    Unreadable { name: String, message: String },
    #[error("{name} is cut short: its header promises {promised} faces but the file holds {held}")]
    Truncated {
        name: String,
        promised: usize,
        held: usize,
    },
    #[error("{name} has {faces} faces, more than the budget of {budget} (MeshOptions::max_faces)")]
    TooBig {
        name: String,
        faces: usize,
        budget: usize,
    },
    #[error("{name}: vertex {corner} of face {face} is not a finite number")]
    NotFinite {
        name: String,
        face: usize,
        corner: usize,
    },
    #[error("{name} has no area: all of its {faces} faces are degenerate (zero area)")]
    NoArea { name: String, faces: usize },
    #[error("{name} has no faces")]
    Empty { name: String },
    #[error("{name}: the edge from vertex {a} to vertex {b} is shared by {count} faces ({}): the mesh is not manifold", list(faces))]
    NonManifold {
        name: String,
        a: u32,
        b: u32,
        count: usize,
        faces: Vec<usize>,
    },
    #[error(
        "{name} is not closed: {edges} edges bound a hole, at faces {}",
        list(faces)
    )]
    Open {
        name: String,
        edges: usize,
        faces: Vec<usize>,
    },
    #[error(
        "{name}: {count} faces turn the other way from their neighbours (flipped), faces {}",
        list(faces)
    )]
    Flipped {
        name: String,
        count: usize,
        faces: Vec<usize>,
    },
    #[error("{name}, line {line}: {message}")]
    Csv {
        name: String,
        line: usize,
        message: String,
    },
    #[error("{name}: row {row} (line {line}) has {len} points but row 1 has {expected}: a point grid needs rows of equal length")]
    Ragged {
        name: String,
        row: usize,
        line: usize,
        len: usize,
        expected: usize,
    },
    #[error("{0}")]
    BadParam(String),
    #[error(transparent)]
    Op(#[from] OpError),
}

/// The first few of a list of face numbers, for messages.
fn list(v: &[usize]) -> String {
    let mut s: Vec<String> = v.iter().take(8).map(|f| f.to_string()).collect();
    if v.len() > 8 {
        s.push(format!("… ({} in all)", v.len()));
    }
    s.join(", ")
}

impl Mesh {
    pub fn new(name: impl Into<String>, vertices: Vec<V3>, faces: Vec<[u32; 3]>) -> Self {
        Mesh {
            name: name.into(),
            vertices,
            faces,
        }
    }

    /// A mesh from loose triangles, vertices closer than `weld` welded into one and the
    /// faces that welding collapsed dropped.
    pub fn from_triangles(name: impl Into<String>, tris: &[[V3; 3]], weld: f64) -> Mesh {
        let mut w = topology::Welder::new(weld);
        let mut faces = Vec::with_capacity(tris.len());
        for t in tris {
            let f = [w.add(t[0]), w.add(t[1]), w.add(t[2])];
            if f[0] != f[1] && f[1] != f[2] && f[0] != f[2] {
                faces.push(f);
            }
        }
        Mesh::new(name, w.into_vertices(), faces)
    }

    /// The corners of face `f`.
    pub fn triangle(&self, f: usize) -> [V3; 3] {
        let [a, b, c] = self.faces[f];
        [
            self.vertices[a as usize],
            self.vertices[b as usize],
            self.vertices[c as usize],
        ]
    }

    /// Every face's corners.
    pub fn triangles(&self) -> impl Iterator<Item = [V3; 3]> + '_ {
        (0..self.faces.len()).map(|f| self.triangle(f))
    }

    /// Twice the area vector of face `f` (right-hand rule).
    pub fn face_area2(&self, f: usize) -> V3 {
        let [a, b, c] = self.triangle(f);
        (b - a).cross(c - a)
    }

    /// The unit normal of face `f` (zero for a degenerate face).
    pub fn face_normal(&self, f: usize) -> V3 {
        self.face_area2(f).unit()
    }

    /// Extents of the vertices used by faces: (min, max); None for a mesh with no faces.
    pub fn bounds(&self) -> Option<(V3, V3)> {
        let mut it = self.faces.iter().flatten();
        let first = self.vertices[*it.next()? as usize];
        let (mut lo, mut hi) = (first, first);
        for &v in it {
            let p = self.vertices[v as usize];
            lo = lo.min(p);
            hi = hi.max(p);
        }
        Some((lo, hi))
    }

    /// Total area of the faces, mm².
    pub fn area(&self) -> f64 {
        (0..self.faces.len())
            .map(|f| self.face_area2(f).len() / 2.0)
            .sum()
    }

    /// Signed volume enclosed (positive when the normals point out), mm³; meaningful for a
    /// closed mesh.
    pub fn volume(&self) -> f64 {
        self.triangles()
            .map(|[a, b, c]| a.dot(b.cross(c)) / 6.0)
            .sum()
    }

    /// The same mesh with every face turned over.
    pub fn flipped(&self) -> Mesh {
        Mesh {
            name: self.name.clone(),
            vertices: self.vertices.clone(),
            faces: self.faces.iter().map(|&[a, b, c]| [a, c, b]).collect(),
        }
    }

    /// Checks that every vertex used is finite and the mesh has area; the reader and the
    /// operations call it so that no NaN reaches the geometry.
    pub fn check_finite(&self) -> Result<(), MeshError> {
        if self.faces.is_empty() {
            return Err(MeshError::Empty {
                name: self.name.clone(),
            });
        }
        for (f, face) in self.faces.iter().enumerate() {
            for (k, &v) in face.iter().enumerate() {
                let ok =
                    (v as usize) < self.vertices.len() && self.vertices[v as usize].is_finite();
                if !ok {
                    return Err(MeshError::NotFinite {
                        name: self.name.clone(),
                        face: f,
                        corner: k,
                    });
                }
            }
        }
        if self.area() <= 0.0 {
            return Err(MeshError::NoArea {
                name: self.name.clone(),
                faces: self.faces.len(),
            });
        }
        Ok(())
    }

    /// The mesh as a closed solid with its normals pointing out: its topology, or the
    /// first reason it is not one (non-manifold edges, holes, flipped faces), by face.
    /// A consistently oriented mesh whose normals all point in is turned over.
    pub fn solid(&self) -> Result<(Mesh, Topology), MeshError> {
        self.check_finite()?;
        let topo = Topology::new(self);
        let r = topo.report(self);
        if let Some(e) = topo.edges.iter().find(|e| e.count > 2) {
            return Err(MeshError::NonManifold {
                name: self.name.clone(),
                a: e.v[0],
                b: e.v[1],
                count: e.count as usize,
                faces: topo.faces_of_edge(self, e),
            });
        }
        if r.boundary_edges > 0 {
            return Err(MeshError::Open {
                name: self.name.clone(),
                edges: r.boundary_edges,
                faces: r.boundary_faces,
            });
        }
        if !r.flipped_faces.is_empty() {
            return Err(MeshError::Flipped {
                name: self.name.clone(),
                count: r.flipped_faces.len(),
                faces: r.flipped_faces,
            });
        }
        if self.volume() < 0.0 {
            let m = self.flipped();
            let t = Topology::new(&m);
            return Ok((m, t));
        }
        Ok((self.clone(), topo))
    }
}
