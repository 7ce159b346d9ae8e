//! Importers and exporters of shape files: the geometry JSON of DESIGN.md (and DXF, SVG, STL).

pub mod chain;
pub mod dxf;
pub mod json;
pub mod svg;
pub mod svg_out;

use crate::geom::Shape;

/// Reads a shape file, choosing the reader by the file name's extension
/// (`.json`; DXF and SVG readers are added beside it).
pub fn read_shape(bytes: &[u8], file: &str) -> Result<Shape, ImportError> {
    let ext = std::path::Path::new(file)
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default();
    match ext.as_str() {
        "json" => json::read(bytes, file),
        "dxf" => dxf::read(bytes, file),
        "svg" => svg::read(bytes, file),
        other => Err(ImportError::invalid(
            file,
            format!("cannot read .{other} files (known: .json, .dxf, .svg)"),
        )),
    }
}

/// How to read a shape file, for the readers that take options.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ReadOptions {
    /// DXF: read only these layers (all when empty).
    pub layers: Vec<String>,
    /// DXF and SVG: chaining and curve tolerance, mm (0: the reader's default, 0.001).
    pub tolerance: f64,
}

/// Reads a shape file like [`read_shape`], with options, and returns the readers'
/// warnings (open contours, gaps, crossings, skipped entities) beside the shape.
pub fn read_shape_with(
    bytes: &[u8],
    file: &str,
    opts: &ReadOptions,
) -> Result<(Shape, Vec<String>), ImportError> {
    let ext = std::path::Path::new(file)
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default();
    let tol = if opts.tolerance > 0.0 {
        opts.tolerance
    } else {
        1e-3
    };
    match ext.as_str() {
        "dxf" => {
            let d = dxf::read_with(
                bytes,
                file,
                &dxf::DxfOptions {
                    layers: opts.layers.clone(),
                    tolerance: tol,
                },
            )?;
            Ok((d.shape, d.warnings))
        }
        "svg" => {
            let d = svg::read_with(bytes, file, tol)?;
            Ok((d.shape, d.warnings))
        }
        _ => read_shape(bytes, file).map(|s| (s, Vec::new())),
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
