//! `machlink offset` end to end: the built binary on temporary files.

use crate::common;
use common::cli::machlink;

#[test]
fn offsets_a_square_to_json_and_svg() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("square.json");
    std::fs::write(
        &input,
        r#"{"units":"mm","paths":[{"closed":true,"vertices":[[0,0,0],[10,0,0],[10,10,0],[0,10,0]]}]}"#,
    )
    .unwrap();
    let out = dir.path().join("out.json");
    let st = machlink()
        .args(["offset", input.to_str().unwrap(), "--distance", "-1", "-o"])
        .arg(&out)
        .status()
        .unwrap();
    assert!(st.success());
    let shape = offset_core::io::json::read(&std::fs::read(&out).unwrap(), "out.json").unwrap();
    assert_eq!(shape.paths.len(), 1);
    assert!((shape.paths[0].area() - 64.0).abs() < 1e-9);

    let out = dir.path().join("grown.json");
    let st = machlink()
        .args([
            "offset",
            input.to_str().unwrap(),
            "--distance",
            "1",
            "--join",
            "chamfer",
        ])
        .arg("-o")
        .arg(&out)
        .status()
        .unwrap();
    assert!(st.success());
    let shape = offset_core::io::json::read(&std::fs::read(&out).unwrap(), "g.json").unwrap();
    assert!((shape.paths[0].area() - 142.0).abs() < 1e-9);

    let svg = dir.path().join("out.svg");
    let st = machlink()
        .args(["offset", input.to_str().unwrap(), "-d", "2", "-o"])
        .arg(&svg)
        .status()
        .unwrap();
    assert!(st.success());
    let text = std::fs::read_to_string(&svg).unwrap();
    assert!(text.starts_with("<svg") && text.matches("<path").count() == 2);
}

/// Two squares 1 mm apart grown by 1 mm are one outline, as the offset of the two together
/// is (each grown alone, they would overlap and cross each other).
#[test]
fn parts_that_grow_into_each_other_merge_into_one_outline() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("two.json");
    std::fs::write(
        &input,
        r#"{"units":"mm","paths":[
            {"closed":true,"vertices":[[0,0,0],[10,0,0],[10,10,0],[0,10,0]]},
            {"closed":true,"vertices":[[11,0,0],[21,0,0],[21,10,0],[11,10,0]]}]}"#,
    )
    .unwrap();
    let out = dir.path().join("grown.json");
    let st = machlink()
        .args(["offset", input.to_str().unwrap(), "--distance", "1", "-o"])
        .arg(&out)
        .status()
        .unwrap();
    assert!(st.success());
    let shape = offset_core::io::json::read(&std::fs::read(&out).unwrap(), "grown.json").unwrap();
    assert_eq!(shape.paths.len(), 1, "one merged outline");
    assert!(offset_core::offset::first_crossing(&shape.paths, 1e-3).is_none());
    // each square grown alone is 100 + 40 + π; where they overlap: the 1 × 10 strip between
    // them and the lens of two unit circles 1 apart (2 acos ½ − ½ √3), half above, half below
    let alone = 140.0 + std::f64::consts::PI;
    let lens = 2.0 * 0.5f64.acos() - 0.5 * 3f64.sqrt();
    let union = 2.0 * alone - (10.0 + lens);
    let area = shape.paths[0].area().abs();
    assert!(
        (area - union).abs() < 1e-6,
        "area {area}, the union's {union}"
    );
}

#[test]
fn bad_input_exits_non_zero_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("bow.json");
    std::fs::write(
        &input,
        r#"{"paths":[{"closed":true,"vertices":[[0,0],[10,10],[10,0],[0,10]]}]}"#,
    )
    .unwrap();
    let out = machlink()
        .args(["offset", input.to_str().unwrap(), "--distance", "1", "-o"])
        .arg(dir.path().join("o.json"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("bow.json") && err.contains("crosses itself"),
        "{err}"
    );
    assert_eq!(err.trim().lines().count(), 1, "{err}");

    let missing = machlink()
        .args([
            "offset",
            "/nonexistent/x.json",
            "--distance",
            "1",
            "-o",
            "/tmp/x.json",
        ])
        .output()
        .unwrap();
    assert!(!missing.status.success());
    assert!(String::from_utf8_lossy(&missing.stderr).contains("/nonexistent/x.json"));
}
