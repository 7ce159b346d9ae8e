//! The sewing job of the stop and reattach tests, as geometry JSON.

/// An open zig-zag seam of `rows` rows, `pitch` mm apart from y = `y0`, each from x = −`half`
/// to `half` and back: geometry JSON in millimetres.
pub fn zigzag_seam(rows: usize, y0: f64, pitch: f64, half: f64) -> String {
    let mut vertices = Vec::new();
    for row in 0..rows {
        let y = y0 + row as f64 * pitch;
        let (a, b) = if row % 2 == 0 {
            (-half, half)
        } else {
            (half, -half)
        };
        vertices.push([a, y, 0.0]);
        vertices.push([b, y, 0.0]);
    }
    serde_json::json!({ "units": "mm", "paths": [ { "closed": false, "vertices": vertices } ] })
        .to_string()
}
