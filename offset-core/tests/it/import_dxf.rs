//! DXF import against real files written by other software, and fuzzing of both readers.

use offset_core::geom::{Point, Segment};
use offset_core::io::dxf::{read_with, DxfOptions};
use offset_core::io::{read_shape, svg};
use proptest::prelude::*;
use std::path::PathBuf;

/// A file of `shared/data/dxf`; a test that needs one fails, naming it, when it is absent
/// (never passes by skipping).
fn data(name: &str) -> Vec<u8> {
    let p = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../shared/data/dxf"
    ))
    .join(name);
    match std::fs::read(&p) {
        Ok(b) => b,
        Err(e) => panic!(
            "{} is needed by this test and cannot be read: {e}",
            p.display()
        ),
    }
}

#[test]
fn loose_lines_and_arcs_chain_into_contours() {
    let b = data("1_polylines.dxf");
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
    let b = data("6_closed_loop_with_arcs.dxf");
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
    let b = data("POLI-ALL210_12.DXF");
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
    let b = data("ASCII_R12.dxf");
    let s = read_shape(&b, "ASCII_R12.dxf").unwrap();
    let segs: usize = s.paths.iter().map(|p| p.segment_count()).sum();
    assert_eq!(segs, 2);
    read_shape(&data("dxf_unicode.dxf"), "dxf_unicode.dxf").unwrap();
    read_shape(
        &data("R12_with_trash_beyond_EOF.dxf"),
        "R12_with_trash_beyond_EOF.dxf",
    )
    .unwrap();
}

#[test]
fn circles_with_radius_zero_or_less_are_named() {
    let b = data("circle_radius_le_0.dxf");
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
    let b = data("6_closed_loop_with_arcs.dxf");
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
    #![proptest_config(ProptestConfig::with_cases(offset_core::check::proptest_cases(300)))]
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

/// A drawing with a header setting `$INSUNITS` (when given), the blocks
/// (name, base point, entities) and the entities.
fn drawing(units: Option<i32>, blocks: &[(&str, (f64, f64), &str)], entities: &str) -> Vec<u8> {
    let mut s = String::new();
    if let Some(u) = units {
        s.push_str(&format!(
            "0\nSECTION\n2\nHEADER\n9\n$INSUNITS\n70\n{u}\n0\nENDSEC\n"
        ));
    }
    s.push_str("0\nSECTION\n2\nBLOCKS\n");
    for (name, (x, y), body) in blocks {
        s.push_str(&format!(
            "0\nBLOCK\n8\n0\n2\n{name}\n70\n0\n10\n{x}\n20\n{y}\n30\n0\n3\n{name}\n{body}0\nENDBLK\n8\n0\n"
        ));
    }
    s.push_str(&format!(
        "0\nENDSEC\n0\nSECTION\n2\nENTITIES\n{entities}0\nENDSEC\n0\nEOF\n"
    ));
    s.into_bytes()
}

/// A closed LWPOLYLINE through the points.
fn lwpoly(layer: &str, pts: &[(f64, f64)]) -> String {
    let mut e = format!("0\nLWPOLYLINE\n8\n{layer}\n90\n{}\n70\n1\n", pts.len());
    for (x, y) in pts {
        e.push_str(&format!("10\n{x}\n20\n{y}\n"));
    }
    e
}

fn square10() -> String {
    lwpoly("0", &[(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0)])
}

/// The vertices of every path, rounded to a micrometre and sorted, to compare as sets.
fn corners(s: &offset_core::geom::Shape) -> Vec<(i64, i64)> {
    let mut v: Vec<(i64, i64)> = s
        .paths
        .iter()
        .flat_map(|p| p.vertices.iter())
        .map(|v| ((v.x * 1e3).round() as i64, (v.y * 1e3).round() as i64))
        .collect();
    v.sort();
    v
}

fn mm(pts: &[(f64, f64)]) -> Vec<(i64, i64)> {
    let mut v: Vec<(i64, i64)> = pts
        .iter()
        .map(|(x, y)| ((x * 1e3).round() as i64, (y * 1e3).round() as i64))
        .collect();
    v.sort();
    v
}

#[test]
fn insunits_in_metres_scale_the_real_drawings_to_mm() {
    for f in ["1_polylines.dxf", "6_closed_loop_with_arcs.dxf"] {
        let b = data(f);
        let d = read_with(&b, f, &DxfOptions::default()).unwrap();
        assert_eq!(d.scale, 1000.0, "{f}: $INSUNITS 6 is metres");
        // the same file read as if unitless is a thousand times smaller
        let text =
            String::from_utf8_lossy(&b).replace("$INSUNITS\n 70\n     6", "$INSUNITS\n 70\n     4");
        let raw = read_with(text.as_bytes(), f, &DxfOptions::default()).unwrap();
        assert_eq!(raw.scale, 1.0, "{f}: the header edit did not take");
        let (bm, br) = (d.shape.bounds(), raw.shape.bounds());
        assert!(
            (bm.width() - 1000.0 * br.width()).abs() < 1e-6 * bm.width(),
            "{f}: {bm:?} vs {br:?}"
        );
        assert!(
            (bm.min.y - 1000.0 * br.min.y).abs() < 1e-6 * bm.height(),
            "{f}"
        );
    }
}

#[test]
fn insunits_in_inches_and_feet_scale_to_mm() {
    for (units, k) in [(1, 25.4), (2, 304.8), (4, 1.0), (5, 10.0), (6, 1000.0)] {
        let b = drawing(
            Some(units),
            &[],
            "0\nLINE\n10\n0\n20\n0\n11\n2\n21\n0\n0\nCIRCLE\n10\n10\n20\n10\n40\n1\n",
        );
        let d = read_with(&b, "u.dxf", &DxfOptions::default()).unwrap();
        assert_eq!(d.scale, k, "$INSUNITS {units}");
        let line = d.shape.paths.iter().find(|p| !p.closed).unwrap();
        assert!(
            (line.length() - 2.0 * k).abs() < 1e-9 * k,
            "$INSUNITS {units}: {line:?}"
        );
        let circle = d.shape.paths.iter().find(|p| p.closed).unwrap();
        assert!(
            (circle.area() - std::f64::consts::PI * k * k).abs() < 1e-9 * k * k,
            "$INSUNITS {units}: circle area {}",
            circle.area()
        );
    }
}

#[test]
fn an_insert_places_its_block_by_base_point_scale_and_rotation() {
    // the square (0,0)-(10,10) of a block based at (5,5), inserted at (100,50), twice the
    // size, turned 90°: corners at (100,50) + R90 · 2 (p - (5,5))
    let b = drawing(
        None,
        &[("SQ", (5.0, 5.0), &square10())],
        "0\nINSERT\n8\nCUT\n2\nSQ\n10\n100\n20\n50\n41\n2\n42\n2\n50\n90\n",
    );
    let s = read_shape(&b, "i.dxf").unwrap();
    assert_eq!(s.paths.len(), 1);
    assert_eq!(
        corners(&s),
        mm(&[(110.0, 40.0), (110.0, 60.0), (90.0, 60.0), (90.0, 40.0)])
    );
}

#[test]
fn minsert_arrays_place_every_cell_along_the_rotated_axes() {
    // 3 columns 30 apart, 2 rows 40 apart, turned 90°: columns step along +Y, rows along -X
    let b = drawing(
        None,
        &[("SQ", (0.0, 0.0), &square10())],
        "0\nINSERT\n2\nSQ\n10\n0\n20\n0\n50\n90\n70\n3\n71\n2\n44\n30\n45\n40\n",
    );
    let s = read_shape(&b, "m.dxf").unwrap();
    assert_eq!(s.paths.len(), 6);
    let mut want = Vec::new();
    for col in 0..3 {
        for row in 0..2 {
            let (ox, oy) = (-40.0 * row as f64, 30.0 * col as f64);
            want.extend([
                (ox, oy),
                (ox, oy + 10.0),
                (ox - 10.0, oy + 10.0),
                (ox - 10.0, oy),
            ]);
        }
    }
    assert_eq!(corners(&s), mm(&want));
}

#[test]
fn nested_blocks_compose_their_placements() {
    // OUTER holds SQ at (20,0) and a circle of radius 2 at (0,0); OUTER is inserted at
    // (1000,0) turned 180°: the square lands on (980,0)-(970,-10), the circle at (1000,0)
    let outer = "0\nINSERT\n2\nSQ\n10\n20\n20\n0\n0\nCIRCLE\n8\n0\n10\n0\n20\n0\n40\n2\n";
    let b = drawing(
        None,
        &[
            ("SQ", (0.0, 0.0), &square10()),
            ("OUTER", (0.0, 0.0), outer),
        ],
        "0\nINSERT\n2\nOUTER\n10\n1000\n20\n0\n50\n180\n",
    );
    let s = read_shape(&b, "n.dxf").unwrap();
    assert_eq!(s.paths.len(), 2);
    let sq = s.paths.iter().find(|p| p.len() == 4).unwrap();
    assert_eq!(
        corners(&offset_core::geom::Shape::new(vec![sq.clone()])),
        mm(&[(980.0, 0.0), (970.0, 0.0), (970.0, -10.0), (980.0, -10.0)])
    );
    let c = s.paths.iter().find(|p| p.len() != 4).unwrap();
    let b = c.bounds();
    assert!(
        (b.min.x - 998.0).abs() < 1e-9 && (b.max.y - 2.0).abs() < 1e-9,
        "{b:?}"
    );
}

#[test]
fn a_block_scaled_unevenly_turns_its_circles_into_ellipses() {
    let b = drawing(
        None,
        &[("C", (0.0, 0.0), "0\nCIRCLE\n10\n0\n20\n0\n40\n10\n")],
        "0\nINSERT\n2\nC\n10\n0\n20\n0\n41\n2\n42\n1\n",
    );
    let tol = 1e-3;
    let s = read_shape(&b, "e.dxf").unwrap();
    assert_eq!(s.paths.len(), 1);
    let p = &s.paths[0];
    assert!(p.closed);
    // every point of the path within the tolerance of the ellipse x²/20² + y²/10² = 1
    // (measured along the normal: |F| / |∇F| to first order)
    for seg in p.segments() {
        for k in 0..=8 {
            let q = seg.point_at(k as f64 / 8.0);
            let f = (q.x / 20.0).powi(2) + (q.y / 10.0).powi(2) - 1.0;
            let g = ((2.0 * q.x / 400.0).powi(2) + (2.0 * q.y / 100.0).powi(2)).sqrt();
            assert!(
                (f / g).abs() <= tol * 1.01,
                "{q:?} is {} from the ellipse",
                f / g
            );
        }
    }
    assert!((p.area().abs() - std::f64::consts::PI * 200.0).abs() < 0.05);
    // fitted with arcs, not hundreds of points
    assert!(p.segment_count() < 200, "{} segments", p.segment_count());
}

#[test]
fn a_mirrored_insert_turns_arcs_the_other_way() {
    let arc = "0\nARC\n10\n0\n20\n0\n40\n5\n50\n0\n51\n90\n";
    let b = drawing(
        None,
        &[("A", (0.0, 0.0), arc)],
        "0\nINSERT\n2\nA\n10\n0\n20\n0\n41\n-1\n42\n1\n",
    );
    let s = read_shape(&b, "a.dxf").unwrap();
    let p = &s.paths[0];
    let b = p.bounds();
    // the quarter from (5,0) to (0,5) mirrored in X: from (-5,0) to (0,5), bulging to (-3.5,3.5)
    assert!(
        (b.min.x + 5.0).abs() < 1e-9 && (b.max.x).abs() < 1e-9,
        "{b:?}"
    );
    let mid = p.segments().next().unwrap().point_at(0.5);
    assert!(
        mid.x < 0.0 && mid.y > 0.0 && (mid.len() - 5.0).abs() < 1e-9,
        "{mid:?}"
    );
}

#[test]
fn entities_on_layer_0_take_the_layer_of_their_insert() {
    let b = drawing(
        None,
        &[(
            "SQ",
            (0.0, 0.0),
            &(square10() + &lwpoly("OTHER", &[(50.0, 0.0), (60.0, 0.0), (60.0, 10.0)])),
        )],
        "0\nINSERT\n8\nCUT\n2\nSQ\n10\n0\n20\n0\n",
    );
    let d = read_with(
        &b,
        "l.dxf",
        &DxfOptions {
            layers: vec!["cut".into()],
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(
        d.shape.paths.len(),
        1,
        "only the square, on the INSERT's layer"
    );
    assert_eq!(d.shape.paths[0].len(), 4);
}

#[test]
fn a_block_that_inserts_itself_is_refused_and_an_undefined_one_warned() {
    let b = drawing(
        None,
        &[(
            "LOOP",
            (0.0, 0.0),
            &(square10() + "0\nINSERT\n2\nLOOP\n10\n1\n20\n0\n"),
        )],
        "0\nINSERT\n5\n7F\n2\nLOOP\n10\n0\n20\n0\n",
    );
    let e = read_shape(&b, "loop.dxf").unwrap_err().to_string();
    assert!(e.contains("nests blocks more than 64 deep"), "{e}");
    // a block that inserts itself twice would double at every level: the placements run out
    let b = drawing(
        None,
        &[(
            "TWO",
            (0.0, 0.0),
            "0\nINSERT\n2\nTWO\n10\n1\n20\n0\n0\nINSERT\n2\nTWO\n10\n0\n20\n1\n",
        )],
        "0\nINSERT\n2\nTWO\n10\n0\n20\n0\n",
    );
    let e = read_shape(&b, "two.dxf").unwrap_err().to_string();
    assert!(
        e.contains("block instances") || e.contains("64 deep"),
        "{e}"
    );
    let b = drawing(None, &[], "0\nINSERT\n5\n9A\n2\nNOPE\n10\n0\n20\n0\n");
    let d = read_with(&b, "u.dxf", &DxfOptions::default()).unwrap();
    assert!(
        d.warnings
            .iter()
            .any(|w| w.contains("INSERT (handle 9A") && w.contains("\"NOPE\"")),
        "{:?}",
        d.warnings
    );
}

#[test]
fn the_real_r12_insert_places_a_block_of_text_only() {
    // ASCII_R12.dxf inserts block *U1, which holds one TEXT: it is read (and skipped as
    // text), and the drawing's two LINEs stay what it cuts
    let b = data("ASCII_R12.dxf");
    let d = read_with(&b, "ASCII_R12.dxf", &DxfOptions::default()).unwrap();
    assert!(
        d.warnings
            .iter()
            .any(|w| w.contains("1 TEXT entity skipped")),
        "{:?}",
        d.warnings
    );
    let segs: usize = d.shape.paths.iter().map(|p| p.segment_count()).sum();
    assert_eq!(segs, 2);
}
