//! `machlink plan` and `machlink preview` as an operator runs them: shape files in, G-code
//! and drawings out, and one clear sentence with a non-zero exit on bad input.

use std::path::Path;
use std::process::Command;

fn machlink(args: &[&str]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_machlink"))
        .args(args)
        .output()
        .expect("machlink runs");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

const PART_SVG: &str = r#"<svg xmlns="http://www.w3.org/2000/svg" width="60mm" height="40mm" viewBox="0 0 60 40">
<path d="M0 0 H60 V40 H0 Z M30 12 a8 8 0 1 0 0.001 0 Z" fill="black" fill-rule="evenodd"/></svg>"#;

#[test]
fn a_pocket_from_svg_plans_posts_and_previews() {
    let dir = tempfile::tempdir().unwrap();
    let svg = dir.path().join("part.svg");
    std::fs::write(&svg, PART_SVG).unwrap();
    let nc = dir.path().join("part.nc");
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let (ok, err) = machlink(&[
        "plan",
        &s(&svg),
        "--op",
        "pocket",
        "--tool-diameter",
        "6",
        "--stepover",
        "40%",
        "--depth",
        "2",
        "--stepdown",
        "1",
        "--post",
        "grbl",
        "-o",
        &s(&nc),
    ]);
    assert!(ok, "{err}");
    let gcode = std::fs::read_to_string(&nc).unwrap();
    // the island is a circle: its passes come out as arcs
    assert!(
        gcode
            .lines()
            .any(|l| l.starts_with("G2") || l.starts_with("G3")),
        "{gcode}"
    );
    let png = dir.path().join("part.png");
    let (ok, err) = machlink(&["preview", &s(&nc), "-o", &s(&png)]);
    assert!(ok, "{err}");
    let bytes = std::fs::read(&png).unwrap();
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
    let over = dir.path().join("over.svg");
    let (ok, err) = machlink(&[
        "preview",
        &s(&svg),
        "--op",
        "profile",
        "--tabs",
        "2",
        "--lead-in",
        "2",
        "-o",
        &s(&over),
    ]);
    assert!(ok, "{err}");
    let drawing = std::fs::read_to_string(&over).unwrap();
    assert!(drawing.contains("stroke-dasharray"), "rapids are dashed");
    assert!(
        drawing.contains(offset_core::preview::LINEAR_COLOUR),
        "the planned cuts are drawn over the part"
    );
    // without --op the part is drawn alone: no tool path at all
    let alone = dir.path().join("alone.svg");
    let (ok, err) = machlink(&["preview", &s(&svg), "-o", &s(&alone)]);
    assert!(ok, "{err}");
    let drawing = std::fs::read_to_string(&alone).unwrap();
    assert!(
        !drawing.contains("stroke-dasharray")
            && !drawing.contains(offset_core::preview::LINEAR_COLOUR)
    );
}

#[test]
fn bad_options_and_files_are_one_clear_sentence() {
    let dir = tempfile::tempdir().unwrap();
    let svg = dir.path().join("part.svg");
    std::fs::write(&svg, PART_SVG).unwrap();
    let out = dir.path().join("x.nc");
    let (s, o) = (svg.to_str().unwrap(), out.to_str().unwrap());
    let (ok, err) = machlink(&["plan", s, "--op", "pocket", "--stepover", "lots", "-o", o]);
    assert!(!ok);
    assert!(
        err.contains("step-over \"lots\" is neither a length in mm"),
        "{err}"
    );
    let (ok, err) = machlink(&["plan", s, "--op", "pocket", "--stepover", "5", "-o", o]);
    assert!(!ok);
    assert!(err.contains("more than the tool diameter"), "{err}");
    let dxf = dir.path().join("c.dxf");
    std::fs::write(&dxf, "0\nSECTION\n2\nENTITIES\n0\nCIRCLE\n5\n1F\n8\nCUT\n10\n0\n20\n0\n40\n10\n0\nENDSEC\n0\nEOF\n").unwrap();
    let d = dxf.to_str().unwrap();
    let (ok, err) = machlink(&["plan", d, "--op", "profile", "--layer", "ENGRAVE", "-o", o]);
    assert!(!ok);
    assert!(err.contains("no geometry on layer(s) ENGRAVE"), "{err}");
    let (ok, err) = machlink(&["plan", d, "--op", "profile", "--layer", "cut", "-o", o]);
    assert!(ok, "{err}");
}
