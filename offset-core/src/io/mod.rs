//! Importers and exporters of shape files: the geometry JSON of DESIGN.md, DXF and SVG, fitted with arcs and refused beyond a documented range.

pub mod chain;
pub mod dxf;
pub mod json;
pub mod svg;
pub mod svg_out;

use crate::biarc::BiarcOptions;
use crate::geom::{Point, Shape};

/// Reads a shape file, choosing the reader by the file name's extension (`.json`, `.dxf`,
/// `.svg`), with the default options of [`ReadOptions`]: see [`read_shape_with`].
pub fn read_shape(bytes: &[u8], file: &str) -> Result<Shape, ImportError> {
    read_shape_with(bytes, file, &ReadOptions::default()).map(|(s, _)| s)
}

/// How to read a shape file, for the readers that take options.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ReadOptions {
    /// DXF: read only these layers; SVG: only the paths under groups with these ids or
    /// Inkscape layer labels (all when empty).
    pub layers: Vec<String>,
    /// Chaining, curve and arc-fitting tolerance, mm (0: the default, 0.001).
    pub tolerance: f64,
    /// DXF: read only entities of these colours (all when empty; see
    /// [`dxf::DxfOptions::colors`]).
    pub colors: Vec<i64>,
}

/// The largest coordinate a shape may have, in mm after units (10 km): beyond it the
/// tolerances of machining (a micrometre) are lost in the rounding of the numbers, and no
/// machine reaches so far. Readers refuse such shapes, naming the path.
pub const MAX_COORDINATE: f64 = 1e7;

/// Reads a shape file like [`read_shape`], with options, and returns the readers'
/// warnings (open contours, gaps, crossings, skipped entities) beside the shape.
///
/// Every reader hands back arcs where the file has dense runs of points: polylines in
/// JSON and DXF (LWPOLYLINE, POLYLINE) are fitted with lines and arcs within the
/// tolerance ([`crate::biarc`]), and curves (DXF SPLINE and ELLIPSE, SVG Béziers) are
/// flattened within half the tolerance and fitted within the other half. Loose DXF LINEs
/// are chained as they are. A shape reaching beyond ±[`MAX_COORDINATE`] mm is refused.
pub fn read_shape_with(
    bytes: &[u8],
    file: &str,
    opts: &ReadOptions,
) -> Result<(Shape, Vec<String>), ImportError> {
    read_shape_timed(bytes, file, opts).map(|(s, w, _)| (s, w))
}

/// How long [`read_shape_timed`] took: the reading, and the arc fitting where it is a
/// step of its own.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ReadTimes {
    /// The file parsed into paths (for DXF and SVG with their fitting, which runs
    /// piece by piece as they read).
    pub parse: std::time::Duration,
    /// The geometry JSON's polylines fitted with lines and arcs, a step after the parse;
    /// `None` for DXF and SVG, whose fitting is inside `parse`.
    pub fit: Option<std::time::Duration>,
}

/// [`read_shape_with`], with the time of its steps.
pub fn read_shape_timed(
    bytes: &[u8],
    file: &str,
    opts: &ReadOptions,
) -> Result<(Shape, Vec<String>, ReadTimes), ImportError> {
    let started = std::time::Instant::now();
    let mut fit = None;
    let ext = std::path::Path::new(file)
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default();
    let tol = if opts.tolerance.is_finite() && opts.tolerance > 0.0 {
        opts.tolerance
    } else {
        1e-3
    };
    let (shape, warnings) = match ext.as_str() {
        "dxf" => {
            let d = dxf::read_with(
                bytes,
                file,
                &dxf::DxfOptions {
                    layers: opts.layers.clone(),
                    tolerance: tol,
                    colors: opts.colors.clone(),
                    ..Default::default()
                },
            )?;
            (d.shape, d.warnings)
        }
        "svg" => {
            let d = svg::read_layers(bytes, file, tol, &opts.layers)?;
            (d.shape, d.warnings)
        }
        "json" => {
            let shape = json::read(bytes, file)?;
            check_range(&shape, file)?;
            let fitting = std::time::Instant::now();
            let (shape, _) = crate::biarc::fit_shape(&shape, &BiarcOptions::with_tolerance(tol));
            fit = Some(fitting.elapsed());
            (shape, Vec::new())
        }
        other => {
            return Err(ImportError::invalid(
                file,
                format!("cannot read .{other} files (known: .json, .dxf, .svg)"),
            ))
        }
    };
    check_range(&shape, file)?;
    let parse = started.elapsed().saturating_sub(fit.unwrap_or_default());
    Ok((shape, warnings, ReadTimes { parse, fit }))
}

/// The drawing's entities that pass near `at` (within ten times the tolerance), as messages
/// name them (`LINE (handle 2A, line 120) on layer CUT`), at most three: what a crossing
/// found while planning is made of. Only DXF files name entities; other files give none.
pub fn entities_at(bytes: &[u8], file: &str, opts: &ReadOptions, at: Point) -> Vec<String> {
    let is_dxf = std::path::Path::new(file)
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("dxf"));
    if !is_dxf {
        return Vec::new();
    }
    let tol = if opts.tolerance.is_finite() && opts.tolerance > 0.0 {
        opts.tolerance
    } else {
        1e-3
    };
    let read = dxf::read_with(
        bytes,
        file,
        &dxf::DxfOptions {
            layers: opts.layers.clone(),
            tolerance: tol,
            colors: opts.colors.clone(),
            ..Default::default()
        },
    );
    match read {
        Ok(d) => d.entities_at(at, 10.0 * tol, 3),
        Err(_) => Vec::new(),
    }
}

/// Refuses a shape that reaches beyond ±[`MAX_COORDINATE`] mm, naming the first path that
/// does (its index and where it reaches).
pub fn check_range(shape: &Shape, file: &str) -> Result<(), ImportError> {
    match shape.first_beyond(MAX_COORDINATE) {
        None => Ok(()),
        Some((i, at)) => Err(ImportError::invalid(
            file,
            format!(
                "path {i} reaches ({}, {}) mm, beyond the ±{MAX_COORDINATE:e} mm (10 km) a shape may span; check the file's units",
                short(at.x),
                short(at.y)
            ),
        )),
    }
}

/// A coordinate in few digits for a message.
fn short(v: f64) -> String {
    if v.abs() >= 1e6 || (v != 0.0 && v.abs() < 1e-3) {
        format!("{v:.3e}")
    } else {
        format!("{v:.3}")
    }
}

/// Why a shape file could not be read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ImportError {
    #[error("{file}: {message}")]
    Invalid { file: String, message: String },
}

impl ImportError {
    pub fn invalid(file: &str, message: impl Into<String>) -> Self {
        ImportError::Invalid {
            file: file.to_string(),
            message: message.into(),
        }
    }
}
