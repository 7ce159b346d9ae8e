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
