//! STL files in and out (binary and ASCII, through the `stl_io` crate), welded on reading.

use super::{Mesh, MeshError, MeshOptions, V3};
use std::io::Cursor;

/// Reads an STL file (binary or ASCII) handed over as bytes: vertices within
/// `opts.weld_tolerance` welded, faces that welding collapsed dropped. `name` is the file
/// name for messages. A mesh with more than `opts.max_faces` faces is refused before it is
/// read; a cut-short file, a NaN or infinite vertex or a mesh with no area is one error
/// sentence naming the face.
pub fn read_stl(bytes: &[u8], name: &str, opts: &MeshOptions) -> Result<Mesh, MeshError> {
    let tris = read_triangles(bytes, name, opts)?;
    let m = Mesh::from_triangles(name, &tris, opts.weld_tolerance);
    if m.faces.is_empty() {
        return Err(MeshError::NoArea {
            name: name.into(),
            faces: tris.len(),
        });
    }
    m.check_finite()?;
    Ok(m)
}

/// The file's triangles as they are written, checked finite, before welding.
pub fn read_triangles(
    bytes: &[u8],
    name: &str,
    opts: &MeshOptions,
) -> Result<Vec<[V3; 3]>, MeshError> {
    let unreadable = |message: String| MeshError::Unreadable {
        name: name.into(),
        message,
    };
    let promised = (bytes.len() >= 84)
        .then(|| u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as usize);
    let exact_binary = promised.is_some_and(|n| 84 + 50 * n as u64 == bytes.len() as u64);
    let text_start = bytes
        .iter()
        .position(|b| !b.is_ascii_whitespace())
        .unwrap_or(bytes.len());
    let ascii = !exact_binary && bytes[text_start..].starts_with(b"solid");
    let mut tris = Vec::new();
    // a text file that begins "solid": every solid's facets; one whose header only happens
    // to begin "solid" but whose bytes are a whole binary STL is read as binary after all
    let binary_fits = promised.is_some_and(|n| 84 + 50 * n as u64 <= bytes.len() as u64);
    let text = if ascii {
        match read_ascii(&bytes[text_start..], name, opts) {
            Ok(t) => Some(t),
            Err(e) if binary_fits && !matches!(e, MeshError::TooBig { .. }) => {
                if is_text(bytes) {
                    return Err(e);
                }
                None
            }
            Err(e) => return Err(e),
        }
    } else {
        None
    };
    if let Some(t) = text {
        tris = t;
    } else {
        let Some(n) = promised else {
            return Err(unreadable(format!(
                "{} bytes is too short for an STL file (a binary one has an 84-byte header)",
                bytes.len()
            )));
        };
        if n > opts.max_faces {
            return Err(MeshError::TooBig {
                name: name.into(),
                faces: n,
                budget: opts.max_faces,
            });
        }
        let held = (bytes.len() - 84) / 50;
        if held < n {
            return Err(MeshError::Truncated {
                name: name.into(),
                promised: n,
                held,
            });
        }
        // only the promised faces: stl_io reads the count from the header
        let mut cur = Cursor::new(&bytes[..84 + 50 * n]);
        let reader = stl_io::create_stl_reader(&mut cur)
            .map_err(|e| unreadable(format!("not an STL file ({e})")))?;
        tris.reserve(n);
        for t in reader {
            let face = tris.len();
            let t = t.map_err(|e| unreadable(format!("face {face} cannot be read: {e}")))?;
            tris.push(triangle(&t, name, face)?);
        }
    }
    if tris.is_empty() {
        return Err(MeshError::Empty { name: name.into() });
    }
    Ok(tris)
}

/// Whether the bytes look like text (no control bytes but whitespace): a text file's
/// parse error is the one to report, not a guess that it was binary.
fn is_text(bytes: &[u8]) -> bool {
    bytes
        .iter()
        .take(4096)
        .all(|&b| b.is_ascii_graphic() || b.is_ascii_whitespace() || b >= 0x80)
}

/// The facets of every `solid … endsolid` block of an ASCII STL, in order. The stored
/// normal is skipped unread (it is recomputed from the corners wherever it matters, and
/// some writers put decimal commas or nothing in it); vertices must be three finite
/// numbers. Errors name the line and the face.
fn read_ascii(text: &[u8], name: &str, opts: &MeshOptions) -> Result<Vec<[V3; 3]>, MeshError> {
    let unreadable = |message: String| MeshError::Unreadable {
        name: name.into(),
        message,
    };
    let mut tris: Vec<[V3; 3]> = Vec::new();
    let mut corners: Vec<V3> = Vec::with_capacity(3);
    let mut in_solid = false;
    let mut in_facet = false;
    let mut solids = 0usize;
    let mut line_no = 0usize;
    for raw in text.split(|&b| b == b'\n') {
        line_no += 1;
        let line = String::from_utf8_lossy(raw);
        let mut words = line.split_whitespace();
        let Some(first) = words.next() else { continue };
        let face = tris.len();
        match first.to_ascii_lowercase().as_str() {
            "solid" if !in_solid => {
                in_solid = true;
                solids += 1;
            }
            "endsolid" if in_solid && !in_facet => in_solid = false,
            "facet" if in_solid && !in_facet => {
                in_facet = true;
                corners.clear();
            }
            "outer" | "endloop" if in_facet => {}
            "vertex" if in_facet => {
                if corners.len() == 3 {
                    return Err(unreadable(format!(
                        "line {line_no}: face {face} has more than three vertices"
                    )));
                }
                let mut p = [0.0f64; 3];
                for (k, v) in p.iter_mut().enumerate() {
                    let w = words.next().ok_or_else(|| {
                        unreadable(format!(
                            "line {line_no}: vertex {} of face {face} has {k} coordinates, not 3",
                            corners.len()
                        ))
                    })?;
                    *v = w.parse::<f64>().map_err(|_| {
                        unreadable(format!(
                            "line {line_no}: vertex {} of face {face} has \"{w}\" where a number belongs",
                            corners.len()
                        ))
                    })?;
                }
                let p = V3::new(p[0], p[1], p[2]);
                if !p.is_finite() {
                    return Err(MeshError::NotFinite {
                        name: name.into(),
                        face,
                        corner: corners.len(),
                    });
                }
                corners.push(p);
            }
            "endfacet" if in_facet => {
                in_facet = false;
                if corners.len() != 3 {
                    return Err(unreadable(format!(
                        "line {line_no}: face {face} has {} vertices, not 3",
                        corners.len()
                    )));
                }
                if tris.len() >= opts.max_faces {
                    return Err(MeshError::TooBig {
                        name: name.into(),
                        faces: tris.len() + 1,
                        budget: opts.max_faces,
                    });
                }
                tris.push([corners[0], corners[1], corners[2]]);
            }
            other => {
                let shown: String = other.chars().take(24).collect();
                return Err(unreadable(format!(
                    "line {line_no}: \"{shown}\" is not an ASCII STL keyword here (face {face} of solid {solids})"
                )));
            }
        }
    }
    if in_solid || in_facet {
        return Err(unreadable(format!(
            "the ASCII STL is cut short in face {} (it ends without \"endsolid\")",
            tris.len()
        )));
    }
    Ok(tris)
}

fn triangle(t: &stl_io::Triangle, name: &str, face: usize) -> Result<[V3; 3], MeshError> {
    let mut out = [V3::ZERO; 3];
    for (k, v) in t.vertices.iter().enumerate() {
        let p = V3::new(v.0[0] as f64, v.0[1] as f64, v.0[2] as f64);
        if !p.is_finite() {
            return Err(MeshError::NotFinite {
                name: name.into(),
                face,
                corner: k,
            });
        }
        out[k] = p;
    }
    Ok(out)
}

/// The mesh as a binary STL (single-precision, as the format is), normals from the
/// right-hand rule.
pub fn write_stl(m: &Mesh) -> Vec<u8> {
    let f32v = |p: V3| stl_io::Vertex::new([p.x as f32, p.y as f32, p.z as f32]);
    let tris: Vec<stl_io::Triangle> = (0..m.faces.len())
        .map(|f| {
            let [a, b, c] = m.triangle(f);
            stl_io::Triangle {
                normal: f32v(m.face_normal(f)),
                vertices: [f32v(a), f32v(b), f32v(c)],
            }
        })
        .collect();
    let mut out = Vec::with_capacity(84 + 50 * tris.len());
    stl_io::write_stl(&mut out, tris.iter()).expect("writing to memory cannot fail");
    out
}

/// The mesh as an ASCII STL (for people and for tools that want text).
pub fn write_ascii_stl(m: &Mesh) -> String {
    use std::fmt::Write;
    let mut s = String::from("solid machlink\n");
    for f in 0..m.faces.len() {
        let n = m.face_normal(f);
        let _ = writeln!(s, "facet normal {:e} {:e} {:e}\n outer loop", n.x, n.y, n.z);
        for p in m.triangle(f) {
            let _ = writeln!(s, "  vertex {:e} {:e} {:e}", p.x, p.y, p.z);
        }
        s.push_str(" endloop\nendfacet\n");
    }
    s.push_str("endsolid machlink\n");
    s
}
