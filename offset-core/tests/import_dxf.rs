//! DXF import against real files written by other software, and fuzzing of both readers.

use offset_core::geom::{Point, Segment};
use offset_core::io::dxf::{read_with, DxfOptions};
use offset_core::io::{read_shape, svg};
use proptest::prelude::*;
use std::path::PathBuf;

/// A file of `shared/data/dxf`; a test that needs one fails, naming it, when it is absent.
fn data(name: &str) -> Option<Vec<u8>> {
    let p = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../shared/data/dxf"
    ))
    .join(name);
    match std::fs::read(&p) {
        Ok(b) => Some(b),
        Err(e) => panic!(
            "{} is needed by this test and cannot be read: {e}",
            p.display()
        ),
    }
}

#[test]
fn loose_lines_and_arcs_chain_into_contours() {
    let Some(b) = data("1_polylines.dxf") else {
        return;
    };
    let d = read_with(&b, "1_polylines.dxf", &DxfOptions::default()).unwrap();
    // $INSUNITS 6: metres
    assert_eq!(d.scale, 1000.0);
    let segs: usize = d.shape.paths.iter().map(|p| p.segment_count()).sum();
    let arcs: usize = d
        .shape
        .paths
        .iter()
        .flat_map(|p| p.segments())
        .filter(|s| matches!(s, Segment::Arc { .. }))
        .count();
    // 52 lines and 22 arcs went in; arcs of up to 90° each stay arcs
    assert!(arcs >= 22, "{arcs} arcs");
    assert!(segs >= 74, "{segs} segments");
    assert!(
        d.shape.paths.len() < 74,
        "nothing chained: {} paths",
        d.shape.paths.len()
    );
    let closed = d.shape.paths.iter().filter(|p| p.closed).count();
    // as drawn: two open chains (a line of bumps, a zigzag), eight closed outlines
    assert_eq!((d.shape.paths.len(), closed), (10, 8), "{:?}", d.warnings);
    // every open contour is reported with its ends
    let open = d.shape.paths.len() - closed;
    assert_eq!(
        d.warnings
            .iter()
            .filter(|w| w.starts_with("open contour"))
            .count(),
        open
    );
}

#[test]
fn a_closed_loop_with_two_arcs() {
    let Some(b) = data("6_closed_loop_with_arcs.dxf") else {
        return;
    };
    let s = read_shape(&b, "6_closed_loop_with_arcs.dxf").unwrap();
    assert_eq!(s.paths.len(), 1, "{s:?}");
    let p = &s.paths[0];
    assert!(p.closed);
    let arcs = p
        .segments()
        .filter(|s| matches!(s, Segment::Arc { .. }))
        .count();
    let lines = p.segment_count() - arcs;
    assert_eq!(lines, 9);
    assert!(arcs >= 2);
    assert!(p.area().abs() > 0.0);
}

#[test]
fn old_style_polylines_with_bulges() {
    let Some(b) = data("POLI-ALL210_12.DXF") else {
        return;
    };
    let s = read_shape(&b, "POLI-ALL210_12.DXF").unwrap();
    assert!(!s.paths.is_empty());
    assert!(s.paths.len() <= 30);
    let bulged = s
        .paths
        .iter()
        .flat_map(|p| p.vertices.iter())
        .filter(|v| v.bulge != 0.0)
        .count();
    assert!(bulged > 0, "no bulges read");
    assert!(s.paths.iter().all(|p| p.is_finite()));
}

#[test]
fn old_headers_unicode_and_trash_after_eof() {
    if let Some(b) = data("ASCII_R12.dxf") {
        let s = read_shape(&b, "ASCII_R12.dxf").unwrap();
        let segs: usize = s.paths.iter().map(|p| p.segment_count()).sum();
        assert_eq!(segs, 2);
    }
    if let Some(b) = data("dxf_unicode.dxf") {
        read_shape(&b, "dxf_unicode.dxf").unwrap();
    }
    if let Some(b) = data("R12_with_trash_beyond_EOF.dxf") {
        read_shape(&b, "R12_with_trash_beyond_EOF.dxf").unwrap();
    }
}

#[test]
fn circles_with_radius_zero_or_less_are_named() {
    let Some(b) = data("circle_radius_le_0.dxf") else {
        return;
    };
    let e = read_shape(&b, "circle_radius_le_0.dxf")
        .unwrap_err()
        .to_string();
    assert!(
        e.starts_with("circle_radius_le_0.dxf: CIRCLE (handle "),
        "{e}"
    );
    assert!(e.contains("a radius must be more than 0"), "{e}");
}

#[test]
fn a_layer_with_nothing_is_a_clear_error() {
    let Some(b) = data("6_closed_loop_with_arcs.dxf") else {
        return;
    };
    let e = read_with(
        &b,
        "x.dxf",
        &DxfOptions {
            layers: vec!["NO_SUCH_LAYER".into()],
            ..Default::default()
        },
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("no geometry on layer(s) NO_SUCH_LAYER"), "{e}");
}

fn mutate(base: &[u8], edits: &[(usize, u8)], cut: usize) -> Vec<u8> {
    let mut b = base.to_vec();
    for &(i, v) in edits {
        if !b.is_empty() {
            let k = i % b.len();
            b[k] = v;
        }
    }
    b.truncate(cut.max(1).min(b.len()));
    b
}

const SMALL_DXF: &str = "0\nSECTION\n2\nHEADER\n9\n$INSUNITS\n70\n4\n0\nENDSEC\n0\nSECTION\n2\nENTITIES\n0\nLINE\n8\n0\n10\n0\n20\n0\n11\n10\n21\n0\n0\nARC\n10\n10\n20\n5\n40\n5\n50\n270\n51\n90\n0\nLWPOLYLINE\n90\n3\n70\n1\n10\n0\n20\n0\n42\n0.5\n10\n5\n20\n0\n10\n5\n20\n5\n0\nSPLINE\n71\n3\n72\n8\n73\n4\n40\n0\n40\n0\n40\n0\n40\n0\n40\n1\n40\n1\n40\n1\n40\n1\n10\n0\n20\n0\n10\n1\n20\n2\n10\n3\n20\n2\n10\n4\n20\n0\n0\nELLIPSE\n10\n0\n20\n0\n11\n5\n21\n0\n40\n0.5\n41\n0\n42\n6.283185307179586\n0\nPOLYLINE\n70\n1\n0\nVERTEX\n10\n0\n20\n0\n42\n1\n0\nVERTEX\n10\n3\n20\n0\n0\nSEQEND\n0\nENDSEC\n0\nEOF\n";

const SMALL_SVG: &str = r#"<svg xmlns="http://www.w3.org/2000/svg" width="50mm" height="50mm" viewBox="0 0 50 50"><path d="M 1 1 L 20 1 Q 30 10 20 20 C 10 30 5 20 1 1 Z" fill="red"/><ellipse cx="30" cy="30" rx="5" ry="3" transform="rotate(30)" stroke="black"/></svg>"#;

#[test]
fn the_fuzz_bases_read_cleanly() {
    let s = read_shape(SMALL_DXF.as_bytes(), "f.dxf").unwrap();
    assert!(s.paths.len() >= 4, "{s:?}");
    let s = svg::read(SMALL_SVG.as_bytes(), "f.svg").unwrap();
    assert_eq!(s.paths.len(), 2);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]
    #[test]
    fn dxf_reader_never_panics(edits in prop::collection::vec((any::<usize>(), any::<u8>()), 0..12), cut in any::<usize>()) {
        let b = mutate(SMALL_DXF.as_bytes(), &edits, cut);
        let _ = read_shape(&b, "fuzz.dxf");
    }

    #[test]
    fn dxf_reader_never_panics_on_digit_swaps(edits in prop::collection::vec((any::<usize>(), prop::sample::select(b"-0123456789.eE\n ".to_vec())), 1..8)) {
        let b = mutate(SMALL_DXF.as_bytes(), &edits, usize::MAX);
        let _ = read_shape(&b, "fuzz.dxf");
    }

    #[test]
    fn svg_reader_never_panics(edits in prop::collection::vec((any::<usize>(), any::<u8>()), 0..12), cut in any::<usize>()) {
        let b = mutate(SMALL_SVG.as_bytes(), &edits, cut);
        let _ = read_shape(&b, "fuzz.svg");
    }

    #[test]
    fn readers_never_panic_on_random_bytes(b in prop::collection::vec(any::<u8>(), 0..400)) {
        let _ = read_shape(&b, "r.dxf");
        let _ = read_shape(&b, "r.svg");
    }
}

/// An ENTITIES section holding just `entity` (group pairs, each line ending in `\n`).
fn one_entity(entity: &str) -> Vec<u8> {
    format!("0\nSECTION\n2\nENTITIES\n0\n{entity}0\nENDSEC\n0\nEOF\n").into_bytes()
}

#[test]
fn huge_angles_are_refused_not_wound_down_forever() {
    // found by the digit-swap fuzzer: one "5" of the full-turn end parameter turned into
    // an "e", making it 6.28e86 radians; unwinding that by 2π at a time never ended
    let e = read_shape(
        &one_entity("ELLIPSE\n10\n0\n20\n0\n11\n5\n21\n0\n40\n0.5\n41\n0\n42\n6.283185307179e86\n"),
        "e.dxf",
    )
    .unwrap_err()
    .to_string();
    assert!(e.starts_with("e.dxf: ELLIPSE (line 5)"), "{e}");
    assert!(
        e.contains("group 42") && e.contains("6.283185307179e86"),
        "{e}"
    );
    // an ARC's angles (degrees) go through the same unwinding
    let e = read_shape(
        &one_entity("ARC\n10\n0\n20\n0\n40\n5\n50\n-1e30\n51\n90\n"),
        "a.dxf",
    )
    .unwrap_err()
    .to_string();
    assert!(e.starts_with("a.dxf: ARC (line 5)"), "{e}");
    assert!(e.contains("group 50") && e.contains("-1e30"), "{e}");
    // angles of a few turns are still fine: -270° to 540° is the quarter from 90° to 180°
    let s = read_shape(
        &one_entity("ARC\n10\n0\n20\n0\n40\n5\n50\n-270\n51\n540\n"),
        "a.dxf",
    )
    .unwrap();
    assert_eq!(s.paths.len(), 1);
    let p = &s.paths[0];
    assert!((p.length() - 2.5 * std::f64::consts::PI).abs() < 1e-9);
    let (a, b) = (p.vertices[0].pos(), p.vertices[p.len() - 1].pos());
    assert!(a.dist(Point::new(0.0, 5.0)) < 1e-9 && b.dist(Point::new(-5.0, 0.0)) < 1e-9);
}

#[test]
fn a_curve_too_big_for_the_tolerance_is_refused_by_name() {
    // a 1000 km ellipse within 0.001 mm would take tens of millions of points
    let e = read_shape(
        &one_entity("ELLIPSE\n5\n3F\n10\n0\n20\n0\n11\n1e9\n21\n0\n40\n0.5\n"),
        "big.dxf",
    )
    .unwrap_err()
    .to_string();
    assert!(e.starts_with("big.dxf: ELLIPSE (handle 3F, line 5)"), "{e}");
    assert!(e.contains("more than 200000 points"), "{e}");
    // the same ellipse at 100 m is read, within the tolerance
    let d = read_with(
        &one_entity("ELLIPSE\n10\n0\n20\n0\n11\n1e5\n21\n0\n40\n0.5\n"),
        "ok.dxf",
        &DxfOptions::default(),
    )
    .unwrap();
    assert_eq!(d.shape.paths.len(), 1);
    assert!(d.shape.paths[0].closed);
}

#[test]
fn huge_curves_in_all_are_refused_before_they_fill_the_memory() {
    // each 2 km ellipse takes about 120 000 points within 0.0005 mm (half the tolerance
    // of 0.001 mm: the other half is the arc fit's); twenty of them pass the drawing's
    // budget of two million
    let e: String = (0..20)
        .map(|i| {
            format!(
                "0\nELLIPSE\n10\n{}\n20\n0\n11\n2e6\n21\n0\n40\n0.5\n",
                i as f64 * 1e7
            )
        })
        .collect();
    let b = format!("0\nSECTION\n2\nENTITIES\n{e}0\nENDSEC\n0\nEOF\n");
    let e = read_shape(b.as_bytes(), "many.dxf")
        .unwrap_err()
        .to_string();
    assert!(
        e.starts_with("many.dxf: the drawing's curves would need more than 2000000 points in all"),
        "{e}"
    );
    assert!(e.contains("(reached at ELLIPSE (line "), "{e}");
    // within 0.1 mm they are read
    let d = read_with(
        b.as_bytes(),
        "many.dxf",
        &DxfOptions {
            tolerance: 0.1,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(d.shape.paths.len(), 20);
    assert!(d.shape.paths.iter().all(|p| p.closed));
}

#[test]
fn a_polyline_of_a_hundred_thousand_vertices_is_read_whole() {
    // the handle of the entity was looked up for every number read: quadratic in its size
    let n = 100_000;
    let mut e = String::from("LWPOLYLINE\n5\nA1\n70\n1\n");
    for i in 0..n {
        let a = std::f64::consts::TAU * i as f64 / n as f64;
        e.push_str(&format!(
            "10\n{}\n20\n{}\n",
            500.0 * a.cos(),
            500.0 * a.sin()
        ));
    }
    let d = read_with(
        &one_entity(&e),
        "ring.dxf",
        &DxfOptions {
            fit: false,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(d.shape.paths.len(), 1);
    assert!(d.shape.paths[0].closed && d.shape.paths[0].len() == n);
    // fitted (the default), the ring comes back as a few arcs of its radius
    let s = read_shape(&one_entity(&e), "ring.dxf").unwrap();
    assert_eq!(s.paths.len(), 1);
    assert!(
        s.paths[0].closed && s.paths[0].len() <= 4,
        "{:?}",
        s.paths[0]
    );
    assert!(s.paths[0]
        .segments()
        .all(|g| matches!(g, Segment::Arc { radius, .. } if (radius - 500.0).abs() < 1e-3)));
}

#[test]
fn fifty_thousand_lines_from_one_centre_chain_in_pairs() {
    // every chain rescanned the used ends at the centre, and every open end was compared
    // with every other for gaps: quadratic in the number of lines
    let n = 50_000;
    let mut e = String::new();
    for i in 0..n {
        e.push_str(&format!("0\nLINE\n10\n0\n20\n0\n11\n{}\n21\n1\n", i + 1));
    }
    let b = format!("0\nSECTION\n2\nENTITIES\n{e}0\nENDSEC\n0\nEOF\n");
    let d = read_with(b.as_bytes(), "star.dxf", &DxfOptions::default()).unwrap();
    assert_eq!(d.shape.paths.len(), n / 2);
    assert!(d.shape.paths.iter().all(|p| !p.closed
        && p.segment_count() == 2
        && p.vertices[1].pos() == Point::new(0.0, 0.0)));
    // the far ends lie 1 mm apart: no gaps to report, every pair is an open contour
    assert!(
        !d.warnings.iter().any(|w| w.starts_with("gap")),
        "{:?}",
        &d.warnings[..3]
    );
    assert_eq!(
        d.warnings
            .iter()
            .filter(|w| w.starts_with("open contour"))
            .count(),
        n / 2
    );
}

#[test]
fn ends_far_out_do_not_overflow_the_chaining_grid() {
    // found by fuzzing with extreme values: 1e300 / the tolerance saturates the grid cell
    // to i64::MAX, and looking at its neighbour overflowed
    let b = one_entity(
        "LINE\n10\n1e300\n20\n-1e300\n11\n0\n21\n0\n0\nLINE\n10\n0\n20\n0\n11\n1\n21\n1\n",
    );
    let d = read_with(&b, "far.dxf", &DxfOptions::default()).unwrap();
    assert_eq!(d.shape.paths.len(), 1);
    let p = &d.shape.paths[0];
    assert_eq!(p.len(), 3);
    assert!(!p.closed);
    assert_eq!(p.vertices[0].pos(), Point::new(1e300, -1e300));
}
