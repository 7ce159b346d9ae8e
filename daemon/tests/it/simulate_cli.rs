//! `machlink simulate` as an operator runs it: a G-code program or a planned pocket
//! replayed against the stock, the worst engagement, air cuts, gouges and material left in
//! the summary (and every move in --json), the engagement drawn, and one clear sentence
//! with a non-zero exit on bad input.

use crate::common;

use std::path::Path;

fn machlink(args: &[&str]) -> (bool, String, String) {
    let out = common::cli::run(args);
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        common::cli::stderr(&out),
    )
}

fn s(p: &Path) -> String {
    p.to_str().unwrap().to_string()
}

/// A slot along Y 0 from outside the stock, then a pass back at Y `step`.
fn slot_then_pass(step: f64) -> String {
    format!("G21 G90\nG0 Z5\nG0 X-10 Y0\nG1 Z-1 F300\nG1 X45 F800\nG1 Y{step}\nG1 X-10\nG0 Z5\n")
}

#[test]
fn a_program_reads_180_degrees_in_its_slot_and_the_closed_form_at_its_step_over() {
    let dir = tempfile::tempdir().unwrap();
    let nc = dir.path().join("slot.nc");
    std::fs::write(&nc, slot_then_pass(1.5)).unwrap();
    let (ok, out, err) = machlink(&[
        "simulate",
        &s(&nc),
        "--stock",
        "0,-10,40,10",
        "--tool",
        "6",
        "--cell",
        "0.05",
    ]);
    assert!(ok, "{err}");
    assert!(out.contains("worst engagement 180.0° at line 5"), "{out}");
    assert!(out.contains("no rapid goes through material"), "{out}");
    // the air before the stock's edge: 10 mm less the tool radius, plus the plunge
    assert!(out.contains("longest air cut"), "{out}");
    // every move in JSON: the pass back at step-over 1.5 mm reads arccos(1 - 2·1.5/6) = 60°
    let (ok, json, err) = machlink(&[
        "simulate",
        &s(&nc),
        "--stock",
        "0,-10,40,10",
        "--tool",
        "6",
        "--cell",
        "0.05",
        "--json",
    ]);
    assert!(ok, "{err}");
    let rep: serde_json::Value = serde_json::from_str(&json).unwrap();
    let moves = rep["moves"].as_array().unwrap();
    let back = moves.iter().find(|m| m["index"] == 5).unwrap();
    let e = back["engagement"].as_f64().unwrap();
    assert!((e - 60.0).abs() < 2.5, "the pass at 1.5 mm reads {e}°");
    let slot = moves.iter().find(|m| m["index"] == 3).unwrap();
    assert_eq!(slot["engagement"].as_f64(), Some(180.0));
}

const PLATE: &str = r#"{ "units": "mm", "paths": [
 { "closed": true, "vertices": [[0,0,0],[40,0,0],[40,30,0],[0,30,0]] },
 { "closed": true, "vertices": [[12,15,1],[20,15,1]] } ] }"#;

#[test]
fn a_planned_pocket_leaves_nothing_and_gouges_nothing_and_a_bad_program_gouges() {
    let dir = tempfile::tempdir().unwrap();
    let plate = dir.path().join("plate.json");
    std::fs::write(&plate, PLATE).unwrap();
    let png = dir.path().join("engagement.png");
    let (ok, out, err) = machlink(&[
        "simulate",
        &s(&plate),
        "--op",
        "pocket",
        "--tool-diameter",
        "6",
        "--depth",
        "2",
        "--stepdown",
        "1",
        "--cell",
        "0.1",
        "-o",
        &s(&png),
    ]);
    assert!(ok, "{err}");
    assert!(out.contains("no gouge"), "{out}");
    assert!(
        out.contains("no material left that the tool could reach"),
        "{out}"
    );
    // a contour-parallel pocket starts each level with a slot round the wall
    assert!(out.contains("worst engagement 180.0°"), "{out}");
    assert_eq!(&std::fs::read(&png).unwrap()[..8], b"\x89PNG\r\n\x1a\n");
    // the same part, a program that runs into the round island (centre 16,15, radius 4)
    let nc = dir.path().join("bad.nc");
    std::fs::write(
        &nc,
        "G0 Z5\nG0 X5 Y5\nG1 Z-2 F300\nG1 X16 Y10 F800\nG0 Z5\n",
    )
    .unwrap();
    let (ok, out, err) = machlink(&[
        "simulate",
        &s(&nc),
        "--stock",
        "0,0,40,30",
        "--tool",
        "6",
        "--part",
        &s(&plate),
        "--depth",
        "2",
        "--cell",
        "0.1",
    ]);
    assert!(ok, "{err}");
    assert!(out.contains("gouges: "), "{out}");
    assert!(out.contains("material left: "), "{out}");
}

#[test]
fn bad_input_is_one_sentence_and_a_failure() {
    let dir = tempfile::tempdir().unwrap();
    let nc = dir.path().join("slot.nc");
    std::fs::write(&nc, slot_then_pass(1.0)).unwrap();
    for (args, says) in [
        (vec!["--stock", "0,0,40", "--tool", "6"], "neither a box"),
        (vec!["--stock", "40,0,0,10", "--tool", "6"], "second corner"),
        (vec!["--tool", "6"], "say where the stock is"),
        (vec!["--stock", "0,0,40,10"], "say which tool"),
        (
            vec!["--stock", "0,0,40,10", "--tool", "0"],
            "--tool must be",
        ),
        (
            vec!["--stock", "0,0,40,10", "--tool", "6", "--cell", "0"],
            "--cell must be",
        ),
    ] {
        let mut all = vec!["simulate", nc.to_str().unwrap()];
        all.extend(args.iter().copied());
        let (ok, _, err) = machlink(&all);
        assert!(!ok, "{args:?} should fail");
        assert!(err.contains(says), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{err}");
    }
}

#[test]
fn plan_with_feed_control_stays_under_the_largest_feed_and_says_the_time_and_the_retracts() {
    let dir = tempfile::tempdir().unwrap();
    let plate = dir.path().join("plate.json");
    std::fs::write(&plate, PLATE).unwrap();
    let nc = dir.path().join("plate.ngc");
    let (ok, _, err) = machlink(&[
        "plan",
        &s(&plate),
        "--op",
        "pocket",
        "--tool-diameter",
        "6",
        "--depth",
        "2",
        "--stepdown",
        "1",
        "--feed",
        "800",
        "--feed-control",
        "--max-feed",
        "2000",
        "--post",
        "linuxcnc",
        "-o",
        &s(&nc),
    ]);
    assert!(ok, "{err}");
    assert!(err.contains("feed control: estimated"), "{err}");
    assert!(err.contains("retracts to the safe height"), "{err}");
    let gcode = std::fs::read_to_string(&nc).unwrap();
    let feeds: Vec<f64> = gcode
        .split_whitespace()
        .filter_map(|w| w.strip_prefix('F'))
        .filter_map(|f| f.parse().ok())
        .collect();
    assert!(feeds.iter().all(|&f| f <= 2000.0), "{feeds:?}");
    // the light cuts run faster than programmed, the heavy ones at about it
    assert!(feeds.iter().any(|&f| f > 900.0), "{feeds:?}");
    assert!(feeds.iter().any(|&f| f < 800.0 && f > 700.0), "{feeds:?}");
}
