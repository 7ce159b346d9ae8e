//! DXF HATCH and binary DXF against drawings that ezdxf writes (offset-core/tests/py/
//! ezdxf_hatches.py): every boundary-path kind (polyline paths with bulges; edge paths of
//! lines, ccw and cw arcs, elliptic arcs and splines), islands under the three hatch
//! styles, several loops in one hatch, a hatch in a block, and each drawing's binary twin.
//! The filled area and the points inside and outside come from the script's own geometry;
//! each region is pocketed and checked by rasterising (every reachable cell cut, no wall
//! or island touched).

use crate::pocket_support::check_coverage;
use offset_core::geom::{Point, Shape};
use offset_core::io::dxf::{read_with, DxfOptions};
use offset_core::ops::{pocket, PocketParams};
use offset_core::toolpath::Tool;
use std::path::{Path, PathBuf};
use std::process::Command;

/// Runs the ezdxf script into a fresh folder; fails, saying how to get ezdxf, when it
/// cannot run.
fn drawings() -> (tempfile::TempDir, serde_json::Value) {
    let dir = tempfile::tempdir().unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/py/ezdxf_hatches.py");
    let python = std::env::var("MACHLINK_PYTHON").unwrap_or_else(|_| "python3".into());
    let run = Command::new(&python)
        .arg(&script)
        .arg(dir.path())
        .output()
        .unwrap_or_else(|e| panic!("the hatch tests need Python 3 with the ezdxf package, which .ci/run installs (pip install -r .ci/requirements.txt); `{python}` did not start: {e}"));
    assert!(
        run.status.success(),
        "the hatch tests need the Python package ezdxf, which .ci/run installs (pip install -r .ci/requirements.txt); {} exited with {}: {}",
        script.display(),
        run.status,
        String::from_utf8_lossy(&run.stderr).trim()
    );
    let expected =
        serde_json::from_slice(&std::fs::read(dir.path().join("expected.json")).unwrap()).unwrap();
    (dir, expected)
}

fn read(dir: &Path, file: &str) -> Shape {
    let p: PathBuf = dir.join(file);
    let d = read_with(&std::fs::read(&p).unwrap(), file, &DxfOptions::default())
        .unwrap_or_else(|e| panic!("{file}: {e}"));
    assert!(
        d.warnings.iter().all(|w| !w.contains("HATCH")),
        "{file}: {:?}",
        d.warnings
    );
    d.shape
}

fn pt(v: &serde_json::Value) -> Point {
    Point::new(v[0].as_f64().unwrap(), v[1].as_f64().unwrap())
}

#[test]
fn hatches_of_every_boundary_kind_become_the_regions_they_fill() {
    let (dir, expected) = drawings();
    for (name, want) in expected.as_object().unwrap() {
        let shape = read(dir.path(), &format!("{name}.dxf"));
        let regions = shape.regions();
        assert_eq!(
            regions.len() as u64,
            want["regions"].as_u64().unwrap(),
            "{name}: regions {regions:?}"
        );
        let area: f64 = regions.iter().map(|r| r.area()).sum();
        let expect = want["area"].as_f64().unwrap();
        // curves are flattened and fitted within 1 µm: the area moves by at most the
        // tolerance times the perimeter
        let perimeter: f64 = regions
            .iter()
            .flat_map(|r| r.boundaries())
            .map(|p| p.length())
            .sum();
        assert!(
            (area - expect).abs() <= 1e-3 * perimeter,
            "{name}: the regions hold {area} mm², the hatch fills {expect} mm²"
        );
        for p in want["inside"].as_array().unwrap() {
            let p = pt(p);
            assert!(
                regions.iter().any(|r| r.contains(p)),
                "{name}: ({}, {}) is filled by the hatch but in no region",
                p.x,
                p.y
            );
        }
        for p in want["outside"].as_array().unwrap() {
            let p = pt(p);
            assert!(
                !regions.iter().any(|r| r.contains(p)),
                "{name}: ({}, {}) is not filled by the hatch but lies in a region",
                p.x,
                p.y
            );
        }
    }
}

#[test]
fn binary_dxf_reads_as_its_ascii_twin() {
    let (dir, expected) = drawings();
    for name in expected.as_object().unwrap().keys() {
        let ascii = read(dir.path(), &format!("{name}.dxf"));
        let binary = read(dir.path(), &format!("{name}_bin.dxf"));
        assert_eq!(ascii, binary, "{name}: the binary twin reads otherwise");
    }
}

#[test]
fn every_hatch_region_pockets_without_touching_a_wall_or_island() {
    let (dir, expected) = drawings();
    let mut p = PocketParams::default();
    p.cut.tool = Tool::flat(2.0);
    p.cut.depth = 1.0;
    p.cut.stepdown = 1.0;
    let r = p.cut.tool.radius();
    for name in expected.as_object().unwrap().keys() {
        for (k, region) in read(dir.path(), &format!("{name}.dxf"))
            .regions()
            .iter()
            .enumerate()
        {
            let one = Shape::new(region.boundaries().cloned().collect());
            let tp = pocket(&one, &p).unwrap_or_else(|e| panic!("{name}, region {k}: {e}"));
            let c = check_coverage(region, &tp, r, -p.cut.depth, 0.2, 0.01);
            assert_eq!(
                c.gouges, 0,
                "{name}, region {k}: the tool enters a wall or island at {:?}",
                c.first_gouge
            );
            assert_eq!(
                c.uncut, 0,
                "{name}, region {k}: {} of {} reachable cells uncut, e.g. at {:?}",
                c.uncut, c.cells, c.first_uncut
            );
        }
    }
}

/// A hatch of every edge kind (line, ccw arc, cw arc, elliptic arc, spline) around a
/// polyline-path island, as group pairs: the fuzz base, in ASCII and in binary.
#[rustfmt::skip]
const HATCH_GROUPS: &[(i32, &str)] = &[
    (0, "SECTION"), (2, "ENTITIES"), (0, "HATCH"), (5, "2A"), (8, "POCKETS"),
    (10, "0"), (20, "0"), (30, "0"), (2, "SOLID"), (70, "1"), (71, "0"), (91, "2"),
    (92, "1"), (93, "5"),
    (72, "1"), (10, "0"), (20, "0"), (11, "30"), (21, "0"),
    (72, "2"), (10, "30"), (20, "10"), (40, "10"), (50, "270"), (51, "360"), (73, "1"),
    (72, "2"), (10, "30"), (20, "10"), (40, "10"), (50, "270"), (51, "360"), (73, "0"),
    (72, "3"), (10, "15"), (20, "20"), (11, "15"), (21, "0"), (40, "0.5"), (50, "0"), (51, "180"), (73, "1"),
    (72, "4"), (94, "3"), (73, "0"), (74, "0"), (95, "8"), (96, "4"),
    (40, "0"), (40, "0"), (40, "0"), (40, "0"), (40, "1"), (40, "1"), (40, "1"), (40, "1"),
    (10, "0"), (20, "20"), (10, "-3"), (20, "13"), (10, "-3"), (20, "7"), (10, "0"), (20, "0"), (97, "0"),
    (97, "0"),
    (92, "2"), (72, "1"), (73, "1"), (93, "4"),
    (10, "10"), (20, "5"), (42, "0"), (10, "20"), (20, "5"), (42, "0.4"), (10, "20"), (20, "10"), (42, "0"), (10, "10"), (20, "10"), (42, "0"),
    (97, "0"), (75, "0"), (76, "1"), (98, "0"),
    (0, "ENDSEC"), (0, "EOF"),
];

fn ascii(groups: &[(i32, &str)]) -> Vec<u8> {
    groups
        .iter()
        .flat_map(|(c, v)| format!("{c}\n{v}\n").into_bytes())
        .collect()
}

/// The groups as binary DXF (R13+: two-byte codes), typed by code as the DXF reference
/// gives them, written here independently of the reader.
fn binary(groups: &[(i32, &str)]) -> Vec<u8> {
    let mut b = b"AutoCAD Binary DXF\r\n\x1a\0".to_vec();
    for (c, v) in groups {
        b.extend((*c as i16).to_le_bytes());
        match c {
            10..=59 => b.extend(v.parse::<f64>().unwrap().to_le_bytes()),
            60..=79 => b.extend(v.parse::<i16>().unwrap().to_le_bytes()),
            90..=99 => b.extend(v.parse::<i32>().unwrap().to_le_bytes()),
            _ => {
                b.extend(v.as_bytes());
                b.push(0);
            }
        }
    }
    b
}

#[test]
fn the_hand_written_hatch_reads_the_same_from_ascii_and_binary() {
    let a = read_with(&ascii(HATCH_GROUPS), "h.dxf", &DxfOptions::default()).unwrap();
    let b = read_with(&binary(HATCH_GROUPS), "h.dxf", &DxfOptions::default()).unwrap();
    assert!(a.warnings.is_empty(), "{:?}", a.warnings);
    assert_eq!(a, b);
    let regions = a.shape.regions();
    assert_eq!(regions.len(), 1, "{regions:?}");
    assert_eq!(regions[0].islands.len(), 1, "{regions:?}");
    // the cw quarter arc from 90° to 0° (stored as the complements 270°, 360°) bounds
    // (40, 10)..(30, 20)
    assert!(regions[0].contains(Point::new(36.0, 16.0)));
    assert!(
        !regions[0].contains(Point::new(15.0, 7.0)),
        "the island is filled"
    );
}

#[test]
fn a_broken_hatch_is_refused_naming_its_handle_layer_and_path() {
    let mut g = HATCH_GROUPS.to_vec();
    let k = g.iter().position(|&(c, v)| c == 72 && v == "3").unwrap();
    g[k].1 = "7";
    let e = read_with(&ascii(&g), "h.dxf", &DxfOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("HATCH (handle 2A")
            && e.contains("layer POCKETS")
            && e.contains("boundary path 0")
            && e.contains("edge of type 7"),
        "{e}"
    );
    let mut g = HATCH_GROUPS.to_vec();
    let k = g.iter().position(|&(c, v)| c == 40 && v == "10").unwrap();
    g[k].1 = "-2";
    let e = read_with(&binary(&g), "h.dxf", &DxfOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("HATCH (handle 2A") && e.contains("radius -2"),
        "{e}"
    );
}

#[test]
fn a_boundary_path_that_does_not_close_is_skipped_with_a_warning() {
    let mut g = HATCH_GROUPS.to_vec();
    let k = g.iter().position(|&(c, v)| c == 11 && v == "30").unwrap();
    g[k].1 = "25"; // the first line stops 5 mm short of the arc
    let d = read_with(&ascii(&g), "h.dxf", &DxfOptions::default()).unwrap();
    assert!(
        d.warnings
            .iter()
            .any(|w| w.contains("HATCH (handle 2A") && w.contains("boundary path 0 is not closed")),
        "{:?}",
        d.warnings
    );
}

#[test]
fn a_binary_dxf_cut_short_is_refused_naming_the_offset() {
    let b = binary(HATCH_GROUPS);
    // inside the arc's radius (group 40, 10.0), and inside the last string (EOF's NUL)
    let mut radius = 40i16.to_le_bytes().to_vec();
    radius.extend(10f64.to_le_bytes());
    let at = b.windows(radius.len()).position(|w| w == radius).unwrap();
    for cut in [at + 5, b.len() - 1] {
        let e = read_with(&b[..cut], "h.dxf", &DxfOptions::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("cut short") && e.contains("byte offset"),
            "cut at {cut}: {e}"
        );
    }
}

fn mutate(base: &[u8], edits: &[(usize, u8)], cut: usize) -> Vec<u8> {
    let mut b = base.to_vec();
    for &(i, v) in edits {
        let k = i % b.len();
        b[k] = v;
    }
    b.truncate(cut.max(1).min(b.len()));
    b
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(offset_core::check::proptest_cases(300)))]
    #[test]
    fn the_hatch_and_binary_readers_never_panic(
        edits in proptest::collection::vec((proptest::prelude::any::<usize>(), proptest::prelude::any::<u8>()), 0..12),
        cut in proptest::prelude::any::<usize>(),
    ) {
        let _ = read_with(&mutate(&ascii(HATCH_GROUPS), &edits, cut), "f.dxf", &DxfOptions::default());
        let _ = read_with(&mutate(&binary(HATCH_GROUPS), &edits, cut), "f.dxf", &DxfOptions::default());
    }
}
