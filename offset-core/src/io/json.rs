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

/// The common file read without serde: an object of `units` (a plain string) and `paths`,
/// each an object of `closed` (true or false) and `vertices` (arrays of numbers), each key
/// at most once, whitespace as JSON has it. Anything else — another key, an escape or a
/// byte past ASCII in a string, a number of more than 19 digits or with a power of ten
/// past 10²², any mistake — gives None, and the file is read by serde_json, which reads
/// the same files to the same values and names the mistakes. Numbers are made as
/// serde_json 1 makes them (without its `float_roundtrip` feature): the digits as an
/// integer, converted to a double, then multiplied or divided once by the power of ten.
struct FastReader<'a> {
    bytes: &'a [u8],
    at: usize,
}

/// 10⁰ … 10²², each exactly a double (and what serde_json's table holds).
const POW10: [f64; 23] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16,
    1e17, 1e18, 1e19, 1e20, 1e21, 1e22,
];

impl<'a> FastReader<'a> {
    fn read(bytes: &'a [u8]) -> Option<FileJson> {
        let mut r = FastReader { bytes, at: 0 };
        let doc = r.file()?;
        r.space();
        (r.at == bytes.len()).then_some(doc)
    }

    fn space(&mut self) {
        while let Some(b' ' | b'\n' | b'\t' | b'\r') = self.bytes.get(self.at) {
            self.at += 1;
        }
    }

    /// The next byte after white space (not taken).
    fn peek(&mut self) -> Option<u8> {
        self.space();
        self.bytes.get(self.at).copied()
    }

    fn take(&mut self, byte: u8) -> Option<()> {
        (self.peek()? == byte).then(|| self.at += 1)
    }

    /// After an element: true for a comma (another follows), false for `close`.
    fn more(&mut self, close: u8) -> Option<bool> {
        let b = self.peek()?;
        self.at += 1;
        match b {
            b',' => Some(true),
            _ if b == close => Some(false),
            _ => None,
        }
    }

    /// An empty object or array right after its opening: takes `close` if it is next.
    fn empty(&mut self, close: u8) -> Option<bool> {
        let empty = self.peek()? == close;
        if empty {
            self.at += 1;
        }
        Some(empty)
    }

    fn string(&mut self) -> Option<&'a str> {
        self.take(b'"')?;
        let start = self.at;
        loop {
            match *self.bytes.get(self.at)? {
                b'"' => break,
                b'\\' | 0..=0x1f | 0x80.. => return None,
                _ => self.at += 1,
            }
        }
        let text = std::str::from_utf8(&self.bytes[start..self.at]).ok()?;
        self.at += 1;
        Some(text)
    }

    fn boolean(&mut self) -> Option<bool> {
        self.space();
        let rest = self.bytes.get(self.at..)?;
        let (value, len) = if rest.starts_with(b"true") {
            (true, 4)
        } else if rest.starts_with(b"false") {
            (false, 5)
        } else {
            return None;
        };
        self.at += len;
        Some(value)
    }

    fn digit(&self) -> Option<u64> {
        match self.bytes.get(self.at) {
            Some(&c @ b'0'..=b'9') => Some(u64::from(c - b'0')),
            _ => None,
        }
    }

    /// Appends a digit to the integer, None where serde_json would leave its fast path.
    fn push_digit(significand: u64, digit: u64) -> Option<u64> {
        significand.checked_mul(10)?.checked_add(digit)
    }

    fn number(&mut self) -> Option<f64> {
        self.space();
        let negative = self.bytes.get(self.at) == Some(&b'-');
        if negative {
            self.at += 1;
        }
        let mut significand = self.digit()?;
        self.at += 1;
        if significand == 0 {
            if self.digit().is_some() {
                return None; // a leading zero
            }
        } else {
            while let Some(d) = self.digit() {
                significand = Self::push_digit(significand, d)?;
                self.at += 1;
            }
        }
        let mut exponent: i32 = 0;
        if self.bytes.get(self.at) == Some(&b'.') {
            self.at += 1;
            while let Some(d) = self.digit() {
                significand = Self::push_digit(significand, d)?;
                exponent -= 1;
                self.at += 1;
            }
            if exponent == 0 {
                return None; // no digit after the point
            }
        }
        if let Some(b'e' | b'E') = self.bytes.get(self.at) {
            self.at += 1;
            let negative_exponent = self.bytes.get(self.at) == Some(&b'-');
            if let Some(b'-' | b'+') = self.bytes.get(self.at) {
                self.at += 1;
            }
            let mut e = self.digit()?;
            self.at += 1;
            while let Some(d) = self.digit() {
                e = e * 10 + d;
                if e > 1000 {
                    return None;
                }
                self.at += 1;
            }
            let e = e as i32;
            exponent = if negative_exponent {
                exponent - e
            } else {
                exponent + e
            };
        }
        let pow = *POW10.get(exponent.unsigned_abs() as usize)?;
        let mut f = significand as f64;
        if exponent >= 0 {
            f *= pow;
        } else {
            f /= pow;
        }
        Some(if negative { -f } else { f })
    }

    fn file(&mut self) -> Option<FileJson> {
        self.take(b'{')?;
        let (mut units, mut paths) = (None, None);
        if !self.empty(b'}')? {
            loop {
                let key = self.string()?;
                self.take(b':')?;
                match key {
                    "units" if units.is_none() => units = Some(self.string()?.to_string()),
                    "paths" if paths.is_none() => paths = Some(self.paths()?),
                    _ => return None,
                }
                if !self.more(b'}')? {
                    break;
                }
            }
        }
        Some(FileJson {
            units: units.unwrap_or_else(mm),
            paths: paths?,
        })
    }

    fn paths(&mut self) -> Option<Vec<PathJson>> {
        self.take(b'[')?;
        let mut paths = Vec::new();
        if self.empty(b']')? {
            return Some(paths);
        }
        loop {
            paths.push(self.path()?);
            if !self.more(b']')? {
                return Some(paths);
            }
        }
    }

    fn path(&mut self) -> Option<PathJson> {
        self.take(b'{')?;
        let (mut closed, mut vertices) = (None, None);
        if !self.empty(b'}')? {
            loop {
                let key = self.string()?;
                self.take(b':')?;
                match key {
                    "closed" if closed.is_none() => closed = Some(self.boolean()?),
                    "vertices" if vertices.is_none() => vertices = Some(self.vertices()?),
                    _ => return None,
                }
                if !self.more(b'}')? {
                    break;
                }
            }
        }
        Some(PathJson {
            closed: closed.unwrap_or(false),
            vertices: vertices?,
        })
    }

    fn vertices(&mut self) -> Option<Vec<VertexJson>> {
        self.take(b'[')?;
        let mut vertices = Vec::new();
        if self.empty(b']')? {
            return Some(vertices);
        }
        loop {
            self.take(b'[')?;
            let mut v = VertexJson {
                len: 0,
                xyb: [0.0; 3],
            };
            if !self.empty(b']')? {
                loop {
                    let x = self.number()?;
                    if let Some(slot) = v.xyb.get_mut(v.len) {
                        *slot = x;
                    }
                    v.len += 1;
                    if !self.more(b']')? {
                        break;
                    }
                }
            }
            vertices.push(v);
            if !self.more(b']')? {
                return Some(vertices);
            }
        }
    }
}

/// Reads the geometry JSON; `file` names the source in errors. Units "mm" and "in" are
/// accepted (inches are scaled to mm).
pub fn read(bytes: &[u8], file: &str) -> Result<Shape, ImportError> {
    if let Some(doc) = FastReader::read(bytes) {
        return shape_of(doc, file);
    }
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
    shape_of(doc, file)
}

/// The shape of a file as read: units, vertex counts and finite coordinates checked.
fn shape_of(doc: FileJson, file: &str) -> Result<Shape, ImportError> {
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

    /// What serde_json reads, as (units, [(closed, [(count, x, y, bulge bits)])]).
    type Read = (String, Vec<(bool, Vec<(usize, [u64; 3])>)>);

    fn as_read(doc: &FileJson) -> Read {
        let paths = doc.paths.iter().map(|p| {
            let vs = p.vertices.iter().map(|v| (v.len, v.xyb.map(f64::to_bits)));
            (p.closed, vs.collect())
        });
        (doc.units.clone(), paths.collect())
    }

    #[test]
    fn the_fast_reader_reads_what_serde_json_reads_or_leaves_the_file_to_it() {
        // numbers in the forms files have (shortest, %.17g, fixed, exponents, integers,
        // negative zero, long and leading-zero fractions, too many digits), documents
        // well and badly formed: wherever the fast reader answers, serde_json gives the
        // same values bit for bit; wherever serde_json refuses, the fast reader does too
        let mut state = 13u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            state >> 11
        };
        let mut numbers: Vec<String> = [
            "0",
            "-0",
            "0.0",
            "-0.0",
            "1",
            "-1",
            "0.1",
            "1e3",
            "1E-3",
            "2.5e+2",
            "-7e0",
            "0.000123",
            "123456789012345678",
            "18446744073709551615",
            "18446744073709551616",
            "1.8446744073709551616",
            "3.14159265358979323846",
            "1e22",
            "1e23",
            "4.5e-22",
            "1e-23",
            "9007199254740993",
            "0.30000000000000004",
            "01",
            "1.",
            ".5",
            "-",
            "+1",
            "1e",
            "1e+",
            "--1",
            "1.5.2",
            "0x10",
            "1e400",
            "NaN",
            "Infinity",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        for _ in 0..3000 {
            let bits = next();
            let scale = 10f64.powi((next() % 10) as i32 - 3);
            let v = (bits as f64 / (1u64 << 53) as f64 - 0.5) * scale;
            numbers.push(match next() % 4 {
                0 => format!("{v}"),
                1 => format!("{v:.6}"),
                2 => format!("{v:e}"),
                _ => format!("{:.3}", v * 1000.0),
            });
        }
        let mut docs = Vec::new();
        for chunk in numbers.chunks(6) {
            let n = |k: usize| chunk[k % chunk.len()].as_str();
            docs.push(format!(
                r#"{{"units": "mm", "paths": [{{"closed": true, "vertices": [[{}, {}], [{}, {}, {}]]}}, {{"vertices": [[{},{}]]}}]}}"#,
                n(0), n(1), n(2), n(3), n(4), n(5), n(0)
            ));
        }
        for doc in [
            r#"{"paths": []}"#,
            r#"{"paths": [], "units": "in"}"#,
            r#" { "paths" : [ { "vertices" : [ ] , "closed" : false } ] } "#,
            "{\"paths\":[{\"vertices\":[[1,2]]}]}\n\t\r",
            r#"{"paths": [], "paths": []}"#,
            r#"{"paths": [{"closed": true, "closed": false, "vertices": []}]}"#,
            r#"{"paths": [], "other": 1}"#,
            r#"{"paths": [{"vertices": [[1,2]], "name": "a"}]}"#,
            r#"{"units": "m\u006d", "paths": []}"#,
            r#"{"units": "mm"}"#,
            r#"{"paths": [{"closed": true}]}"#,
            r#"{"paths": [{"closed": null, "vertices": []}]}"#,
            r#"{"paths": [{"closed": 1, "vertices": []}]}"#,
            r#"{"paths": [{"vertices": [[1,2],]}]}"#,
            r#"{"paths": [{"vertices": [[1,2,]]}]}"#,
            r#"{"paths": [{"vertices": [[1 2]]}]}"#,
            r#"{"paths": [{"vertices": [[1,"a"]]}]}"#,
            r#"{"paths": [{"vertices": [7]}]}"#,
            r#"{"paths": [{"vertices": [[1,2]]}]} x"#,
            r#"{"paths": [{"vertices": [[1,2]]}]"#,
            r#"{"paths": [{"vertices": [[1,2],[3,4,5,6,7]]}],}"#,
            r#"["mm", [[true, [[1, 2]]]]]"#,
            r#"{"paths": [{"vertices": [[truex]]}]}"#,
            r#"{"paths": [{"closed": truex, "vertices": []}]}"#,
            "{\"units\": \"\u{e9}\", \"paths\": []}",
            "",
            "{",
        ] {
            docs.push(doc.to_string());
        }
        let mut answered = 0;
        for doc in &docs {
            let fast = FastReader::read(doc.as_bytes());
            let serde = serde_json::from_slice::<FileJson>(doc.as_bytes());
            match (&fast, &serde) {
                (Some(f), Ok(s)) => {
                    answered += 1;
                    assert_eq!(as_read(f), as_read(s), "{doc}");
                }
                (Some(_), Err(e)) => {
                    panic!("serde_json refuses {doc} ({e}), the fast reader read it")
                }
                (None, _) => {}
            }
        }
        // and it is the fast reader that reads the common files
        assert!(
            answered * 10 >= docs.len() * 7,
            "{answered} of {}",
            docs.len()
        );
        assert!(FastReader::read(br#"{"units": "mm", "paths": [{"closed": true, "vertices": [[60.5,-0.25],[1e-7,2,0.5]]}]}"#).is_some());
    }

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
