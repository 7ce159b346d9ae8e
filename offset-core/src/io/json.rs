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
/// byte past ASCII in a string, a number of more than 19 digits (leading zeros of a
/// fraction included) or with an exponent of
/// more than three digits, any mistake — gives None, and the file is read by serde_json, which reads
/// the same files to the same values and names the mistakes. Numbers are made as
/// serde_json 1 makes them (without its `float_roundtrip` feature): the digits as an
/// integer, converted to a double, then multiplied or divided once by the power of ten
/// (divided by 10³⁰⁸ first while the power is past it).
struct FastReader<'a> {
    bytes: &'a [u8],
    at: usize,
}

/// 10⁰ … 10³⁰⁸ as serde_json's table has them (each the double nearest).
const POW10: [f64; 309] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16,
    1e17, 1e18, 1e19, 1e20, 1e21, 1e22, 1e23, 1e24, 1e25, 1e26, 1e27, 1e28, 1e29, 1e30, 1e31, 1e32,
    1e33, 1e34, 1e35, 1e36, 1e37, 1e38, 1e39, 1e40, 1e41, 1e42, 1e43, 1e44, 1e45, 1e46, 1e47, 1e48,
    1e49, 1e50, 1e51, 1e52, 1e53, 1e54, 1e55, 1e56, 1e57, 1e58, 1e59, 1e60, 1e61, 1e62, 1e63, 1e64,
    1e65, 1e66, 1e67, 1e68, 1e69, 1e70, 1e71, 1e72, 1e73, 1e74, 1e75, 1e76, 1e77, 1e78, 1e79, 1e80,
    1e81, 1e82, 1e83, 1e84, 1e85, 1e86, 1e87, 1e88, 1e89, 1e90, 1e91, 1e92, 1e93, 1e94, 1e95, 1e96,
    1e97, 1e98, 1e99, 1e100, 1e101, 1e102, 1e103, 1e104, 1e105, 1e106, 1e107, 1e108, 1e109, 1e110,
    1e111, 1e112, 1e113, 1e114, 1e115, 1e116, 1e117, 1e118, 1e119, 1e120, 1e121, 1e122, 1e123,
    1e124, 1e125, 1e126, 1e127, 1e128, 1e129, 1e130, 1e131, 1e132, 1e133, 1e134, 1e135, 1e136,
    1e137, 1e138, 1e139, 1e140, 1e141, 1e142, 1e143, 1e144, 1e145, 1e146, 1e147, 1e148, 1e149,
    1e150, 1e151, 1e152, 1e153, 1e154, 1e155, 1e156, 1e157, 1e158, 1e159, 1e160, 1e161, 1e162,
    1e163, 1e164, 1e165, 1e166, 1e167, 1e168, 1e169, 1e170, 1e171, 1e172, 1e173, 1e174, 1e175,
    1e176, 1e177, 1e178, 1e179, 1e180, 1e181, 1e182, 1e183, 1e184, 1e185, 1e186, 1e187, 1e188,
    1e189, 1e190, 1e191, 1e192, 1e193, 1e194, 1e195, 1e196, 1e197, 1e198, 1e199, 1e200, 1e201,
    1e202, 1e203, 1e204, 1e205, 1e206, 1e207, 1e208, 1e209, 1e210, 1e211, 1e212, 1e213, 1e214,
    1e215, 1e216, 1e217, 1e218, 1e219, 1e220, 1e221, 1e222, 1e223, 1e224, 1e225, 1e226, 1e227,
    1e228, 1e229, 1e230, 1e231, 1e232, 1e233, 1e234, 1e235, 1e236, 1e237, 1e238, 1e239, 1e240,
    1e241, 1e242, 1e243, 1e244, 1e245, 1e246, 1e247, 1e248, 1e249, 1e250, 1e251, 1e252, 1e253,
    1e254, 1e255, 1e256, 1e257, 1e258, 1e259, 1e260, 1e261, 1e262, 1e263, 1e264, 1e265, 1e266,
    1e267, 1e268, 1e269, 1e270, 1e271, 1e272, 1e273, 1e274, 1e275, 1e276, 1e277, 1e278, 1e279,
    1e280, 1e281, 1e282, 1e283, 1e284, 1e285, 1e286, 1e287, 1e288, 1e289, 1e290, 1e291, 1e292,
    1e293, 1e294, 1e295, 1e296, 1e297, 1e298, 1e299, 1e300, 1e301, 1e302, 1e303, 1e304, 1e305,
    1e306, 1e307, 1e308,
];

impl<'a> FastReader<'a> {
    fn read(bytes: &'a [u8]) -> Option<Shape> {
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

    /// Takes a run of digits into the integer (wrapping: [`Self::number`] refuses more than
    /// 19 digits in all, which cannot overflow); returns how many there were.
    fn digits(&mut self, significand: &mut u64) -> usize {
        let start = self.at;
        while let Some(&c) = self.bytes.get(self.at) {
            let d = c.wrapping_sub(b'0');
            if d > 9 {
                break;
            }
            *significand = significand.wrapping_mul(10).wrapping_add(u64::from(d));
            self.at += 1;
        }
        self.at - start
    }

    fn number(&mut self) -> Option<f64> {
        self.space();
        let negative = self.bytes.get(self.at) == Some(&b'-');
        if negative {
            self.at += 1;
        }
        let mut significand = self.digit()?;
        self.at += 1;
        let mut count = 1;
        if significand == 0 {
            if self.digit().is_some() {
                return None; // a leading zero
            }
        } else {
            count += self.digits(&mut significand);
        }
        let mut exponent: i32 = 0;
        if self.bytes.get(self.at) == Some(&b'.') {
            self.at += 1;
            let fraction = self.digits(&mut significand);
            if fraction == 0 {
                return None; // no digit after the point
            }
            count += fraction;
            exponent = -(fraction as i32);
        }
        // below 10^19 the integer is what serde_json's checked one is (past it, it may
        // leave its fast path: so does this reader, for all of the file)
        if count > 19 {
            return None;
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
        let mut f = significand as f64;
        loop {
            match POW10.get(exponent.unsigned_abs() as usize) {
                Some(&pow) => {
                    if exponent >= 0 {
                        f *= pow;
                        if f.is_infinite() {
                            return None; // out of range: serde_json says so
                        }
                    } else {
                        f /= pow;
                    }
                    break;
                }
                None => {
                    if f == 0.0 {
                        break;
                    }
                    if exponent >= 0 {
                        return None;
                    }
                    f /= 1e308;
                    exponent += 308;
                }
            }
        }
        Some(if negative { -f } else { f })
    }

    /// The whole file as a shape: units known ("mm" or "in"), every vertex of two or three
    /// numbers, every path of two vertices or more (else None: serde_json's reading then
    /// names the mistake). Vertices go straight into the shape's vectors (no vector of
    /// numbers per file first), scaled once the units are known (they may come last).
    fn file(&mut self) -> Option<Shape> {
        let (mut units, mut paths) = (None, None);
        self.object(|me, key| {
            match key {
                "units" if units.is_none() => units = Some(me.string()?),
                "paths" if paths.is_none() => paths = Some(me.paths()?),
                _ => return None,
            }
            Some(())
        })?;
        let scale = match units.unwrap_or("mm") {
            "mm" => 1.0,
            "in" | "inch" => 25.4,
            _ => return None,
        };
        let mut paths = paths?;
        for (_, vs) in &mut paths {
            for v in vs.iter_mut() {
                // as the reading below scales them (by one for millimetres)
                *v = Vertex::new(v.x * scale, v.y * scale, v.bulge);
            }
        }
        Some(Shape::new(
            paths
                .into_iter()
                .map(|(closed, vs)| Polyline::new(vs, closed))
                .collect(),
        ))
    }

    /// An object: `field` reads each member's value after its key (None refuses the file).
    fn object(&mut self, mut field: impl FnMut(&mut Self, &'a str) -> Option<()>) -> Option<()> {
        self.take(b'{')?;
        if self.empty(b'}')? {
            return Some(());
        }
        loop {
            let key = self.string()?;
            self.take(b':')?;
            field(self, key)?;
            if !self.more(b'}')? {
                return Some(());
            }
        }
    }

    fn paths(&mut self) -> Option<Vec<(bool, Vec<Vertex>)>> {
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

    fn path(&mut self) -> Option<(bool, Vec<Vertex>)> {
        let (mut closed, mut vertices) = (None, None);
        self.object(|me, key| {
            match key {
                "closed" if closed.is_none() => closed = Some(me.boolean()?),
                "vertices" if vertices.is_none() => vertices = Some(me.vertices()?),
                _ => return None,
            }
            Some(())
        })?;
        let vertices = vertices?;
        (vertices.len() >= 2).then_some((closed.unwrap_or(false), vertices))
    }

    fn vertices(&mut self) -> Option<Vec<Vertex>> {
        self.take(b'[')?;
        let mut vertices = Vec::new();
        if self.empty(b']')? {
            return Some(vertices);
        }
        loop {
            self.take(b'[')?;
            let mut xyb = [0.0; 3];
            let mut len = 0;
            if !self.empty(b']')? {
                loop {
                    *xyb.get_mut(len)? = self.number()?;
                    len += 1;
                    if !self.more(b']')? {
                        break;
                    }
                }
            }
            if len < 2 {
                return None;
            }
            vertices.push(Vertex::new(xyb[0], xyb[1], xyb[2]));
            if !self.more(b']')? {
                return Some(vertices);
            }
        }
    }
}

/// Reads the geometry JSON; `file` names the source in errors. Units "mm" and "in" are
/// accepted (inches are scaled to mm).
pub fn read(bytes: &[u8], file: &str) -> Result<Shape, ImportError> {
    if let Some(shape) = FastReader::read(bytes) {
        return Ok(shape);
    }
    read_by_serde(bytes, file)
}

/// [`read`] by serde_json alone: the files the fast reader leaves, and their mistakes.
fn read_by_serde(bytes: &[u8], file: &str) -> Result<Shape, ImportError> {
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

    /// A shape's every number, bit for bit, and each path's closure.
    fn bits(shape: &Shape) -> Vec<(bool, Vec<[u64; 3]>)> {
        let path = |p: &Polyline| {
            let vs = p
                .vertices
                .iter()
                .map(|v| [v.x, v.y, v.bulge].map(f64::to_bits));
            (p.closed, vs.collect())
        };
        shape.paths.iter().map(path).collect()
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
            "7.3478807948841188e-15",
            "-2.4492935982947064e-16",
            "1e-300",
            "1e308",
            "1e309",
            "1.7976931348623157e308",
            "2.5e-320",
            "4.9e-324",
            "1e-330",
            "123456e-330",
            "0e999",
            "0e1001",
            "1e-999",
            "1e-1001",
            "0.00000000000000000000000001",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        for _ in 0..3000 {
            let bits = next();
            let scale = 10f64.powi((next() % 10) as i32 - 3);
            let v = (bits as f64 / (1u64 << 53) as f64 - 0.5) * scale;
            numbers.push(match next() % 5 {
                0 => format!("{v}"),
                1 => format!("{v:.6}"),
                2 => format!("{v:e}"),
                3 => format!("{:.16e}", v * 1e-12),
                _ => format!("{:.3}", v * 1000.0),
            });
        }
        let mut docs = Vec::new();
        for chunk in numbers.chunks(6) {
            let n = |k: usize| chunk[k % chunk.len()].as_str();
            docs.push(format!(
                r#"{{"units": "mm", "paths": [{{"closed": true, "vertices": [[{}, {}], [{}, {}, {}]]}}, {{"vertices": [[{},{}],[{},{}]]}}]}}"#,
                n(0), n(1), n(2), n(3), n(4), n(5), n(0), n(2), n(4)
            ));
        }
        for doc in [
            r#"{"paths": []}"#,
            r#"{"paths": [{"vertices": [[1,2],[3,4,0.5]]}], "units": "in"}"#,
            r#"{"units": "inch", "paths": [{"vertices": [[1.5,2],[3,4,0.5]], "closed": true}]}"#,
            r#"{"units": "m", "paths": [{"vertices": [[1,2],[3,4]]}]}"#,
            r#"{"units": 1, "paths": [{"vertices": [[1,2],[3,4]]}]}"#,
            r#"{"paths": [{"vertices": [[1,2],[3]]}]}"#,
            r#"{"paths": [{"vertices": [[1,2],[3,4,5,6]]}]}"#,
            r#"{"paths": [{"vertices": [[1,2],[]]}]}"#,
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
            let serde = read_by_serde(doc.as_bytes(), "f.json");
            match (&fast, &serde) {
                (Some(f), Ok(s)) => {
                    answered += 1;
                    assert_eq!(bits(f), bits(s), "{doc}");
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
        assert!(FastReader::read(br#"{"units": "mm", "paths": [{"closed": true, "vertices": [[60.5,-0.25],[1e-7,2,0.5],[7.3478807948841188e-15,1e-300]]}]}"#).is_some());
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
