//! The named adversarial cases in tests/regressions/: each offset must give the expected
//! number of loops and area (closed forms, written in each file) and keep its distance.

use crate::common::*;
use offset_core::offset::{offset_shape, Join, OffsetOptions};

#[test]
fn regression_cases() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/regressions");
    let mut names: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .collect();
    names.sort();
    assert!(names.len() >= 8);
    for path in names {
        let doc: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
        let name = doc["name"].as_str().unwrap();
        let geom = serde_json::to_vec(&doc["geometry"]).unwrap();
        let shape = offset_core::io::json::read(&geom, name).unwrap();
        let d = doc["distance"].as_f64().unwrap();
        let join = match doc["join"].as_str().unwrap() {
            "miter" => Join::Miter,
            "chamfer" => Join::Chamfer,
            _ => Join::Round,
        };
        let opts = OffsetOptions {
            join,
            ..Default::default()
        };
        let out = offset_shape(&shape, d, &opts).unwrap();
        let loops = doc["expect"]["loops"].as_u64().unwrap() as usize;
        assert_eq!(out.paths.len(), loops, "{name}: loops");
        let area = doc["expect"]["area"].as_f64().unwrap();
        let got = total_area(&out.paths);
        let slack = 1e-3 * total_length(&out.paths) + 1e-9 * area.abs().max(1.0);
        let slack = if area.abs() < 1e-3 {
            slack.min(0.05 * area.abs().max(1e-12)) + 1e-12
        } else {
            slack
        };
        assert!(
            (got - area).abs() <= slack,
            "{name}: area {got}, expected {area}"
        );
        if join == Join::Round {
            assert_offset(&shape.paths, &out.paths, d, 1e-3);
        }
    }
}
