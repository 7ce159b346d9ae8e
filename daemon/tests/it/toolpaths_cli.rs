//! Tool paths as `machlink plan` writes them for GRBL: a dense polyline from CAD comes out
//! as arcs, and the planner's figures are printed.

use crate::common;
use common::cli::run as machlink;

/// The moves of a GRBL program that go somewhere in XY: (G word, radius from I/J if an arc).
fn xy_moves(gcode: &str) -> Vec<(u32, Option<f64>)> {
    let (mut x, mut y, mut motion) = (0.0f64, 0.0f64, 0u32);
    let mut out = Vec::new();
    for line in gcode.lines() {
        let mut w = std::collections::HashMap::new();
        for word in line.split_whitespace() {
            let (l, v) = word.split_at(1);
            if let Ok(v) = v.parse::<f64>() {
                w.insert(l.to_string(), v);
            }
        }
        if let Some(&g) = w.get("G") {
            if g <= 3.0 {
                motion = g as u32;
            }
        }
        let (nx, ny) = (*w.get("X").unwrap_or(&x), *w.get("Y").unwrap_or(&y));
        if (nx - x).hypot(ny - y) > 1e-9 && motion >= 1 {
            let r = (motion >= 2).then(|| w["I"].hypot(w["J"]));
            out.push((motion, r));
        }
        (x, y) = (nx, ny);
    }
    out
}

#[test]
fn a_dense_circle_profiled_outside_comes_out_as_a_few_arcs_of_the_offset_radius() {
    let dir = tempfile::tempdir().unwrap();
    for n in [1000usize, 10000] {
        let vertices: Vec<[f64; 3]> = (0..n)
            .map(|i| {
                let a = std::f64::consts::TAU * i as f64 / n as f64;
                [300.0 * a.cos(), 300.0 * a.sin(), 0.0]
            })
            .collect();
        let json = serde_json::json!({ "units": "mm", "paths": [ { "closed": true, "vertices": vertices } ] });
        let input = dir.path().join(format!("circle{n}.json"));
        std::fs::write(&input, json.to_string()).unwrap();
        let out = dir.path().join(format!("circle{n}.nc"));
        let o = machlink(&[
            "plan",
            input.to_str().unwrap(),
            "--op",
            "profile",
            "--side",
            "outside",
            "--tool-diameter",
            "100",
            "--depth",
            "1",
            "--tolerance",
            "0.01",
            "--post",
            "grbl",
            "-o",
            out.to_str().unwrap(),
        ]);
        let said = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{said}");
        assert!(
            said.contains("estimated time") && said.contains("arcs"),
            "{said}"
        );
        let moves = xy_moves(&std::fs::read_to_string(&out).unwrap());
        assert!(
            moves.len() <= 8,
            "{n} points: {} cutting moves in XY: {moves:?}",
            moves.len()
        );
        for (g, r) in &moves {
            let r = r.unwrap_or_else(|| panic!("{n} points: a G{g} line where an arc belongs"));
            assert!((r - 350.0).abs() < 1e-3, "{n} points: an arc of radius {r}");
        }
    }
}
