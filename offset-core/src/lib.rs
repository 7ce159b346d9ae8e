//! offset-core: machlink's geometry. It holds the shapes operators hand us (points,
//! polylines whose segments are lines or bulge arcs, regions of an outer boundary with
//! islands) and the readers that parse them from JSON, DXF and SVG bytes with dense runs
//! of points fitted into arcs, the offset kernel that grows and shrinks them (pair-wise
//! interference removal after Choi & Park 1999 and Park 2001), the operations that turn
//! shapes into tool paths (with entries that never plunge into material) and stitch paths,
//! the Toolpath IR those operations hand to the posts, and what a planner shows of a tool
//! path: its figures (lengths, estimated time) and a preview drawing. It does no I/O beyond
//! parsing bytes handed to it, and needs no async runtime.

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
