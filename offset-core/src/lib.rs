//! offset-core: machlink's geometry. It holds the shapes operators hand us (points,
//! polylines whose segments are lines or bulge arcs, regions of an outer boundary with
//! islands) and the readers that parse them from JSON, DXF and SVG bytes with dense runs
//! of points fitted into arcs, the offset kernel that grows and shrinks them (pair-wise
//! interference removal after Choi & Park 1999 and Park 2001), the operations that turn
//! shapes into tool paths (with entries that never plunge into material) and stitch paths,
//! the Toolpath IR those operations hand to the posts, and what a planner shows of a tool
//! path: its figures (lengths, estimated time) and a preview drawing.
//! For 3D work it holds triangle meshes read from STL (welded, their defects reported by
//! face), their offsets by multiple normals (Kim & Yang 2005), z-level roughing on their
//! slices, drop-cutter finishing with ball, flat and bull cutters, and bicubic surfaces
//! fitted to grids of measured points (`mesh`, docs/3d.md).
//! It does no I/O beyond parsing bytes handed to it, and needs no async runtime (the
//! drop-cutter spreads rows over rayon's thread pool).

pub mod biarc;
pub mod check;
pub mod cutsim;
pub mod flatten;
pub mod geom;
pub mod heap;
pub mod io;
pub mod mesh;
pub mod offset;
pub mod ops;
pub mod preview;
pub mod preview3d;
pub mod stats;
pub mod stitch;
pub mod toolpath;

#[cfg(test)]
mod test_rng;

pub use geom::{Bounds, Point, Polyline, Region, Segment, Shape, Vertex};
pub use toolpath::{Move, Tool, ToolKind, Toolpath, P3};
