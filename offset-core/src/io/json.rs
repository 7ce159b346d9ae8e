//! The geometry JSON: `{ "units": "mm", "paths": [ { "closed": true, "vertices": [[x, y, bulge], …] } ] }`.

use super::ImportError;
use crate::geom::{Polyline, Shape, Vertex};
use serde::{Deserialize, Serialize};

#[derive(Serialize, Deserialize)]
struct FileJson {
    #[serde(default = "mm")]
    units: String,
    paths: Vec<PathJson>,
}

fn mm() -> String {
    "mm".into()
}

#[derive(Serialize, Deserialize)]
struct PathJson {
    #[serde(default)]
    closed: bool,
    vertices: Vec<Vec<f64>>,
}

/// Reads the geometry JSON; `file` names the source in errors. Units "mm" and "in" are
/// accepted (inches are scaled to mm).
pub fn read(bytes: &[u8], file: &str) -> Result<Shape, ImportError> {
    let doc: FileJson = serde_json::from_slice(bytes).map_err(|e| {
        ImportError::invalid(
            file,
            format!(
                "not valid geometry JSON at line {}, column {}: {e}",
                e.line(),
                e.column()
            ),
        )
    })?;
    let scale = match doc.units.as_str() {
        "mm" => 1.0,
        "in" | "inch" => 25.4,
        other => {
            return Err(ImportError::invalid(
                file,
                format!("unknown units \"{other}\" (use \"mm\" or \"in\")"),
            ))
        }
    };
    let mut paths = Vec::with_capacity(doc.paths.len());
    for (pi, p) in doc.paths.iter().enumerate() {
        let mut vs = Vec::with_capacity(p.vertices.len());
        for (vi, v) in p.vertices.iter().enumerate() {
            if v.len() != 2 && v.len() != 3 {
                return Err(ImportError::invalid(
                    file,
                    format!(
                        "path {pi}, vertex {vi}: expected [x, y] or [x, y, bulge], got {} numbers",
                        v.len()
                    ),
                ));
            }
            let bulge = v.get(2).copied().unwrap_or(0.0);
            if !(v[0].is_finite() && v[1].is_finite() && bulge.is_finite()) {
                return Err(ImportError::invalid(
                    file,
                    format!("path {pi}, vertex {vi}: coordinates must be finite numbers"),
                ));
            }
            vs.push(Vertex::new(v[0] * scale, v[1] * scale, bulge));
        }
        if vs.len() < 2 {
            return Err(ImportError::invalid(
                file,
                format!(
                    "path {pi} has {} vertices; a path needs at least 2",
                    vs.len()
                ),
            ));
        }
        paths.push(Polyline::new(vs, p.closed));
    }
    Ok(Shape::new(paths))
}

/// Writes a shape as geometry JSON (mm).
pub fn write(shape: &Shape) -> String {
    let doc = FileJson {
        units: "mm".into(),
        paths: shape
            .paths
            .iter()
            .map(|p| PathJson {
                closed: p.closed,
                vertices: p.vertices.iter().map(|v| vec![v.x, v.y, v.bulge]).collect(),
            })
            .collect(),
    };
    serde_json::to_string_pretty(&doc).expect("geometry JSON always serialises")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_errors() {
        let src = br#"{ "units": "mm", "paths": [ { "closed": true, "vertices": [[0,0,0], [100,0,0], [100,50,0.4142], [0,50,0]] } ] }"#;
        let s = read(src, "a.json").unwrap();
        assert_eq!(s.paths.len(), 1);
        assert_eq!(s.paths[0].vertices[2].bulge, 0.4142);
        assert_eq!(read(write(&s).as_bytes(), "b.json").unwrap(), s);
        let e = read(br#"{"paths":[{"vertices":[[0,0],[1]]}]}"#, "c.json").unwrap_err();
        assert!(e.to_string().contains("path 0, vertex 1"), "{e}");
        let e = read(b"{", "d.json").unwrap_err();
        assert!(
            e.to_string().starts_with("d.json: not valid geometry JSON"),
            "{e}"
        );
        let inch = read(
            br#"{"units":"in","paths":[{"vertices":[[1,0],[2,0]]}]}"#,
            "e",
        )
        .unwrap();
        assert_eq!(inch.paths[0].vertices[1].x, 50.8);
    }
}
