//! Importers and exporters of shape files: the geometry JSON of DESIGN.md (and DXF, SVG, STL).

pub mod json;

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
