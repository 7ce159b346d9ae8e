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
    vertices: Vec<VertexJson>,
}

/// One vertex as the file has it: `[x, y]` or `[x, y, bulge]`, read without a vector of
/// its own (a file of 10,000 vertices made as many allocations); `len` counts the numbers
/// the file gave, so a vertex of another length is refused with its count.
struct VertexJson {
    len: usize,
    xyb: [f64; 3],
}

impl Serialize for VertexJson {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeSeq;
        let mut seq = s.serialize_seq(Some(self.len))?;
        for v in &self.xyb[..self.len.min(3)] {
            seq.serialize_element(v)?;
        }
        seq.end()
    }
}

impl<'de> Deserialize<'de> for VertexJson {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Numbers;
        impl<'de> serde::de::Visitor<'de> for Numbers {
            type Value = VertexJson;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a sequence")
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(
                self,
                mut seq: A,
            ) -> Result<VertexJson, A::Error> {
                let mut v = VertexJson {
                    len: 0,
                    xyb: [0.0; 3],
                };
                while let Some(x) = seq.next_element::<f64>()? {
                    if let Some(slot) = v.xyb.get_mut(v.len) {
                        *slot = x;
                    }
                    v.len += 1;
                }
                Ok(v)
            }
        }
        d.deserialize_seq(Numbers)
    }
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
            if v.len != 2 && v.len != 3 {
                return Err(ImportError::invalid(
                    file,
                    format!(
                        "path {pi}, vertex {vi}: expected [x, y] or [x, y, bulge], got {} numbers",
                        v.len
                    ),
                ));
            }
            let [x, y, bulge] = v.xyb;
            if !(x.is_finite() && y.is_finite() && bulge.is_finite()) {
                return Err(ImportError::invalid(
                    file,
                    format!("path {pi}, vertex {vi}: coordinates must be finite numbers"),
                ));
            }
            vs.push(Vertex::new(x * scale, y * scale, bulge));
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
                vertices: p
                    .vertices
                    .iter()
                    .map(|v| VertexJson {
                        len: 3,
                        xyb: [v.x, v.y, v.bulge],
                    })
                    .collect(),
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
        let e = read(br#"{"paths":[{"vertices":[[0,0],[1,2,3,4]]}]}"#, "c.json").unwrap_err();
        assert!(
            e.to_string()
                .contains("vertex 1: expected [x, y] or [x, y, bulge], got 4 numbers"),
            "{e}"
        );
        let e = read(br#"{"paths":[{"vertices":[[0,0],[1,"a"]]}]}"#, "c.json").unwrap_err();
        assert!(
            e.to_string().contains("not valid geometry JSON at line 1"),
            "{e}"
        );
        let e = read(br#"{"paths":[{"vertices":[[0,0],7]]}]}"#, "c.json").unwrap_err();
        assert!(e.to_string().contains("expected a sequence"), "{e}");
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
