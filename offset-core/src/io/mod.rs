//! Importers and exporters of shape files: the geometry JSON of DESIGN.md (and DXF, SVG, STL).

pub mod json;
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
        other => Err(ImportError::invalid(
            file,
            format!("cannot read .{other} files (known: .json)"),
        )),
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
