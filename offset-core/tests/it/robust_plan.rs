//! Robust to scale: every file in `shared/data/dxf`, the same drawings scaled and moved
//! far out, squares from a nanometre to 1e300 mm, and mutated drawings either plan or are
//! refused with a sentence; none aborts (no recursion grows with the input, so nothing
//! overflows the stack), and nothing beyond ±1e7 mm plans into an empty program.

use offset_core::geom::{Point, Polyline, Shape};
use offset_core::io::{read_shape, read_shape_with, ReadOptions, MAX_COORDINATE};
use offset_core::ops::{pocket, profile, Cutting, OpError, PocketParams, ProfileParams, Stepover};
use offset_core::toolpath::{Tool, Toolpath};
use proptest::prelude::*;
use std::path::PathBuf;

/// The drawings of `shared/data/dxf` (see its README).
const FILES: [&str; 7] = [
    "1_polylines.dxf",
    "6_closed_loop_with_arcs.dxf",
    "POLI-ALL210_12.DXF",
    "ASCII_R12.dxf",
    "dxf_unicode.dxf",
    "circle_radius_le_0.dxf",
    "R12_with_trash_beyond_EOF.dxf",
];

/// A file of `shared/data/dxf`; the test fails, naming it, when it is absent.
fn data(name: &str) -> Vec<u8> {
    let p = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../shared/data/dxf"
    ))
    .join(name);
    std::fs::read(&p).unwrap_or_else(|e| {
        panic!(
            "{} is needed by this test and cannot be read: {e}",
            p.display()
        )
    })
}

fn cut(tool: f64) -> Cutting {
    Cutting {
        tool: Tool::flat(tool),
        ..Default::default()
    }
}

/// A refusal is one sentence that says something.
fn sentence(what: &str, e: &dyn std::fmt::Display) {
    let s = e.to_string();
    assert!(
        s.len() > 10 && !s.contains('\n'),
        "{what}: refused with \"{s}\""
    );
}

/// Pocket and profile `shape` with a few tools: each plans a program that goes somewhere,
/// or is refused with a sentence. Returns how many planned.
fn plan_all(what: &str, shape: &Shape) -> usize {
    let mut planned = 0;
    for tool in [3.0, 50.0] {
        let results: [(&str, Result<Toolpath, OpError>); 2] = [
            (
                "pocket",
                pocket(
                    shape,
                    &PocketParams {
                        cut: cut(tool),
                        stepover: Stepover::Percent(40.0),
                    },
                ),
            ),
            (
                "profile",
                profile(
                    shape,
                    &ProfileParams {
                        cut: cut(tool),
                        ..Default::default()
                    },
                ),
            ),
        ];
        for (op, r) in results {
            let what = format!("{what}, {op} with a {tool} mm tool");
            match r {
                Ok(tp) => {
                    let (cut, _) = tp.lengths();
                    assert!(cut > 0.0, "{what}: a program that cuts nothing");
                    let b = tp.bounds().unwrap();
                    assert!(
                        b.min.x.abs().max(b.max.x.abs()) <= 2.0 * MAX_COORDINATE,
                        "{what}: {b:?}"
                    );
                    planned += 1;
                }
                Err(e) => sentence(&what, &e),
            }
        }
    }
    planned
}

#[test]
fn every_shared_dxf_drawing_plans_or_is_refused_with_a_sentence() {
    for f in FILES {
        match read_shape_with(&data(f), f, &ReadOptions::default()) {
            Ok((shape, _)) => {
                let n = plan_all(f, &shape);
                eprintln!("{f}: {n} of 4 plans made");
            }
            Err(e) => sentence(f, &e),
        }
    }
}

#[test]
fn the_metres_drawing_pocketed_with_a_3_mm_tool_is_refused_not_overflowed() {
    let (shape, _) = read_shape_with(
        &data("1_polylines.dxf"),
        "1_polylines.dxf",
        &ReadOptions::default(),
    )
    .unwrap();
    // 300 m across: two of its outlines cross each other, which the pocket says
    let e = pocket(
        &shape,
        &PocketParams {
            cut: cut(3.0),
            stepover: Stepover::Percent(40.0),
        },
    )
    .unwrap_err();
    sentence("1_polylines.dxf", &e);
    // its closed outlines that do not cross are still far too big for a 3 mm tool
    let ok: Vec<Polyline> = shape
        .paths
        .iter()
        .filter(|p| {
            p.closed && offset_core::check::first_crossing(std::slice::from_ref(*p), 1e-3).is_none()
        })
        .cloned()
        .collect();
    assert!(!ok.is_empty());
    let big = Shape::new(ok);
    let e = pocket(
        &big,
        &PocketParams {
            cut: cut(3.0),
            stepover: Stepover::Percent(40.0),
        },
    );
    match e {
        Err(e) => {
            let s = e.to_string();
            assert!(
                s.contains("passes, more than 100000") || s.contains("crosses"),
                "{s}"
            );
        }
        Ok(tp) => assert!(tp.lengths().0 > 0.0),
    }
}

fn square_json(side: f64) -> Vec<u8> {
    format!(
        r#"{{"paths":[{{"closed":true,"vertices":[[0,0],[{side:e},0],[{side:e},{side:e}],[0,{side:e}]]}}]}}"#
    )
    .into_bytes()
}

#[test]
fn squares_from_a_nanometre_to_1e300_mm_plan_or_are_refused() {
    for side in [1e-9, 1e-3, 1.0, 1e3, 1e6, 2e7, 1e15, 1e300] {
        let what = format!("a square of side {side:e} mm");
        let square = Shape::new(vec![Polyline::rect(
            Point::new(0.0, 0.0),
            Point::new(side, side),
        )]);
        plan_all(&what, &square);
        match read_shape(&square_json(side), "square.json") {
            Ok(shape) => {
                assert!(side <= MAX_COORDINATE, "{what}: read");
                plan_all(&what, &shape);
            }
            Err(e) => {
                assert!(side > MAX_COORDINATE, "{what}: {e}");
                let s = e.to_string();
                assert!(s.contains("path 0") && s.contains("beyond"), "{what}: {s}");
            }
        }
    }
    // and refused by the operations themselves, not planned into nothing
    for side in [1e15, 1e300] {
        let square = Shape::new(vec![Polyline::rect(
            Point::new(0.0, 0.0),
            Point::new(side, side),
        )]);
        let e = pocket(
            &square,
            &PocketParams {
                cut: cut(3.0),
                stepover: Stepover::Percent(40.0),
            },
        )
        .unwrap_err();
        assert!(matches!(e, OpError::OutOfRange { path: 0, .. }), "{e}");
        assert!(e.to_string().contains("path 0 reaches"), "{e}");
    }
}

/// `shape` scaled by `k` about the origin and moved by `by`.
fn scaled(shape: &Shape, k: f64, by: Point) -> Shape {
    let mut s = shape.clone();
    for p in &mut s.paths {
        for v in &mut p.vertices {
            v.x = v.x * k + by.x;
            v.y = v.y * k + by.y;
        }
    }
    s
}

#[test]
fn the_shared_drawings_scaled_and_moved_far_out_plan_or_are_refused() {
    for f in FILES {
        let Ok((shape, _)) = read_shape_with(&data(f), f, &ReadOptions::default()) else {
            continue;
        };
        // in mm, most of these drawings are small (or, in metres, huge): each at a few
        // scales that bring it to every size from a hair to beyond the range
        let span = shape
            .bounds()
            .width()
            .max(shape.bounds().height())
            .max(1e-9);
        for target in [0.01, 10.0, 1000.0, 1e9] {
            for by in [Point::new(0.0, 0.0), Point::new(9e6, -9e6)] {
                let what = format!("{f} scaled to {target} mm, moved by {by:?}");
                plan_all(&what, &scaled(&shape, target / span, by));
            }
        }
    }
}

const SMALL_DXF: &str = "0\nSECTION\n2\nHEADER\n9\n$INSUNITS\n70\n4\n0\nENDSEC\n0\nSECTION\n2\nENTITIES\n0\nLWPOLYLINE\n90\n4\n70\n1\n10\n0\n20\n0\n10\n40\n20\n0\n42\n0.3\n10\n40\n20\n30\n10\n0\n20\n30\n0\nCIRCLE\n10\n20\n20\n15\n40\n5\n0\nLINE\n10\n60\n20\n0\n11\n90\n21\n10\n0\nENDSEC\n0\nEOF\n";

proptest! {
    #![proptest_config(ProptestConfig::with_cases(offset_core::check::proptest_cases(64)))]

    /// Digits swapped in a small drawing (sizes, units, bulges that become huge or tiny):
    /// it reads and plans, or is refused, every time.
    #[test]
    fn mutated_drawings_plan_or_are_refused(
        edits in prop::collection::vec((any::<usize>(), prop::sample::select(b"-0123456789.e".to_vec())), 1..6)
    ) {
        let mut b = SMALL_DXF.as_bytes().to_vec();
        for (i, v) in edits {
            let k = i % b.len();
            if b[k].is_ascii_digit() || b[k] == b'.' || b[k] == b'-' {
                b[k] = v;
            }
        }
        match read_shape(&b, "m.dxf") {
            Ok(shape) => { plan_all("mutated", &shape); }
            Err(e) => sentence("mutated", &e),
        }
    }
}
