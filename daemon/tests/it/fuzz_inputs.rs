//! Fuzz-style properties of what the daemon takes from a client: shape files (geometry JSON,
//! DXF, SVG), G-code files through the machine's checks, and the API's job JSON. Any input is
//! read or refused with a sentence, never a panic, in time bounded by its size; a G-code file
//! checked as it streams in is refused or taken exactly as the whole file is.
//! Cases per property: 4000, scaled by `PROPTEST_CASES / 256`.

use machlink::core::check::{gcode_program, GcodeCheck};
use machlink::core::intake::{self, Input, JobSpec};
use machlink::core::machine::{MachineConfig, WorkArea};
use proptest::prelude::*;

/// 4000 cases, or `PROPTEST_CASES` when set, like every property test (docs/testing.md).
fn cases() -> u32 {
    offset_core::check::proptest_cases(4000)
}

fn machine() -> MachineConfig {
    let mut m = MachineConfig::new(
        &machlink::core::registry::standard(),
        "mill",
        "sim-grbl",
        serde_json::json!({}),
    )
    .unwrap();
    m.max_feed = Some(2000.0);
    m.work_area = Some(WorkArea {
        min: [-50.0, -50.0, -20.0],
        max: [50.0, 50.0, 20.0],
    });
    m
}

const SQUARE: &str = r#"{"units":"mm","paths":[{"closed":true,"vertices":[[0,0,0],[40,0,0],[40,40,0.5],[0,40,0]]}]}"#;
const DXF: &str = "0\nSECTION\n2\nENTITIES\n0\nLWPOLYLINE\n8\n0\n90\n3\n70\n1\n10\n0\n20\n0\n10\n10\n20\n0\n42\n0.5\n10\n10\n20\n10\n0\nCIRCLE\n8\n0\n10\n5\n20\n5\n40\n2\n0\nENDSEC\n0\nEOF\n";
const SVG: &str = r#"<svg xmlns="http://www.w3.org/2000/svg" width="50mm" height="50mm" viewBox="0 0 50 50"><path d="M 1 1 L 20 1 A 5 5 0 0 1 20 20 Z"/><circle cx="30" cy="30" r="5"/></svg>"#;

fn mutate(base: &str, edits: &[(usize, u8)], cut: usize) -> Vec<u8> {
    let mut b = base.as_bytes().to_vec();
    for (at, v) in edits {
        let i = at % b.len();
        b[i] = *v;
    }
    b.truncate(cut % (b.len() + 1));
    b
}

fn gcode_lines() -> impl Strategy<Value = Vec<String>> {
    let word = prop::sample::select(vec![
        "G0", "G1", "G2", "G3", "G20", "G21", "G90", "G91", "G10", "G92", "G53", "X", "Y", "Z",
        "I", "J", "R", "F", "F9000", "M3", "M6", "M30", "S1000", "1", "-3", "0.5", "45", "60",
        "1e9", "(", ")", ";", "%", "$H", " ", "?", "\t", "é", "T1",
    ]);
    prop::collection::vec(
        prop::collection::vec(word, 0..8).prop_map(|w| w.concat()),
        0..40,
    )
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(cases()))]

    #[test]
    fn shape_readers_read_or_refuse_any_file(which in 0usize..3,
            edits in prop::collection::vec((any::<usize>(), any::<u8>()), 0..10),
            cut in any::<usize>()) {
        let (base, name) = [(SQUARE, "f.json"), (DXF, "f.dxf"), (SVG, "f.svg")][which];
        let bytes = mutate(base, &edits, cut);
        match offset_core::io::read_shape(&bytes, name) {
            Ok(_) => {}
            Err(e) => prop_assert!(!e.to_string().is_empty()),
        }
    }

    #[test]
    fn gcode_files_are_checked_or_refused_the_same_streamed_or_whole(lines in gcode_lines()) {
        let m = machine();
        let text = lines.join("\n");
        let whole = gcode_program("f.nc", &text, &m);
        let mut check = GcodeCheck::new("f.nc", &m);
        let mut kept = Vec::new();
        let mut streamed = Ok(());
        for (i, l) in text.lines().enumerate() {
            match check.line(i + 1, l) {
                Ok(Some(c)) => kept.push(c.line),
                Ok(None) => {}
                Err(e) => { streamed = Err(e); break; }
            }
        }
        match (whole, streamed) {
            (Ok(p), Ok(())) => prop_assert_eq!(p.lines, kept),
            (Err(a), Err(b)) => prop_assert_eq!(a, b),
            (a, b) => prop_assert!(false, "whole {:?} but streamed {:?}", a.map(|p| p.lines), b),
        }
    }

    #[test]
    fn job_json_is_read_or_refused(edits in prop::collection::vec((any::<usize>(), any::<u8>()), 0..8),
            cut in any::<usize>()) {
        let base = serde_json::json!({
            "machine": "mill",
            "input": { "file_name": "square.json", "file_text": SQUARE },
            "operation": { "op": "profile", "side": "inside", "cut": { "tool": { "diameter": 3 }, "depth": 1 } },
            "tolerance": 0.01
        }).to_string();
        let bytes = mutate(&base, &edits, cut);
        if let Ok(spec) = serde_json::from_slice::<JobSpec>(&bytes) {
            let m = machine();
            let _ = intake::plan(&spec, intake::Target::Machine(&m));
        }
    }

    #[test]
    fn any_bytes_as_a_job_are_refused_without_panic(bytes in prop::collection::vec(any::<u8>(), 0..300)) {
        let _ = serde_json::from_slice::<JobSpec>(&bytes);
        let spec = JobSpec {
            machine: Some("mill".into()),
            input: Input::from_bytes("x.nc", bytes),
            operation: None,
            operations: Vec::new(),
            tolerance: None,
            layers: Vec::new(),
            post: None,
        };
        let m = machine();
        let _ = intake::plan(&spec, intake::Target::Machine(&m));
    }
}

#[test]
fn deeply_nested_json_is_refused_not_recursed_into() {
    let deep = format!("{}{}", "[".repeat(100_000), "]".repeat(100_000));
    assert!(serde_json::from_str::<JobSpec>(&deep).is_err());
    let e = serde_json::from_str::<serde_json::Value>(&deep).unwrap_err();
    assert!(e.to_string().contains("recursion limit"), "{e}");
}
