//! The integration tests of offset-core, in one binary: each former test file is a module
//! here, so the crate and its dev-dependencies (Clipper2, cavalier_contours, proptest) are
//! linked once instead of once per file. New test modules go here: add the file beside
//! this one and its `mod` line below. A test is named by its module:
//! `cargo test -p offset-core --test it corpus::` runs what was `--test corpus`.

mod common;
mod mesh_support;
mod pocket_support;

mod adaptive;
mod biarc;
mod corpus;
mod cutsim;
mod dropcutter;
mod feed_control;
mod finish3d;
mod flatten;
mod import_dxf;
mod import_hatch;
mod mesh_input;
mod mesh_offset;
mod mesh_offset_trimmed;
mod offset_closed;
mod offset_closure;
mod offset_closure_sliced;
mod offset_distances;
mod offset_open;
mod offset_regions;
mod offset_regressions;
mod offset_robust;
mod opencamlib_interop;
mod pocket;
mod pocket_links;
mod profile_entries;
mod profile_links;
mod profile_sides;
mod robust_plan;
mod rough3d;
mod rough_links;
mod soup3d;
mod stitch;
mod stitch_rows;
mod surface;
mod toolpath_fit;
