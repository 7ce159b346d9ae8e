//! offset-core: machlink's geometry. It holds the shapes operators hand us (points,
//! polylines whose segments are lines or bulge arcs, regions of an outer boundary with
//! islands), the offset kernel that grows and shrinks them (pair-wise interference
//! removal after Choi & Park 1999 and Park 2001), the operations that turn shapes into
//! tool paths and stitch paths, and the Toolpath IR those operations hand to the posts.
//! It does no I/O beyond parsing bytes handed to it, and needs no async runtime.

pub mod biarc;
pub mod check;
pub mod flatten;
pub mod geom;
pub mod io;
pub mod offset;
pub mod ops;
pub mod preview;
pub mod stats;
pub mod stitch;
pub mod toolpath;

pub use geom::{Bounds, Point, Polyline, Region, Segment, Shape, Vertex};
pub use toolpath::{Move, Tool, ToolKind, Toolpath, P3};
