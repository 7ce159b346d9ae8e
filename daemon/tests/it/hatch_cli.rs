//! `machlink plan … --op pocket` on drawings of DXF hatches that ezdxf writes
//! (offset-core/tests/py/ezdxf_hatches.py): a hatch-only drawing plans a pocket whose
//! every cutting move lies in the hatched area, and a drawing saved as binary DXF plans a
//! program byte-identical to its ASCII twin's.

use crate::common::cli::{run, stderr};
use offset_core::geom::Point;
use std::path::Path;
use std::process::Command;

/// Runs the ezdxf script into `dir`; fails, saying how to get ezdxf, when it cannot.
fn write_drawings(dir: &Path) -> serde_json::Value {
    let script =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../offset-core/tests/py/ezdxf_hatches.py");
    let python = std::env::var("MACHLINK_PYTHON").unwrap_or_else(|_| "python3".into());
    let out = Command::new(&python)
        .arg(&script)
        .arg(dir)
        .output()
        .unwrap_or_else(|e| panic!("the hatch tests need Python 3 with the ezdxf package, which .ci/run installs (pip install -r .ci/requirements.txt); `{python}` did not start: {e}"));
    assert!(
        out.status.success(),
        "the hatch tests need the Python package ezdxf, which .ci/run installs (pip install -r .ci/requirements.txt); {} exited with {}: {}",
        script.display(),
        out.status,
        String::from_utf8_lossy(&out.stderr).trim()
    );
    serde_json::from_slice(&std::fs::read(dir.join("expected.json")).unwrap()).unwrap()
}

/// Plans a 2 mm pocket, 1 mm deep, of `dxf` (copied to `part.dxf` in `under`, so the
/// file's name cannot differ between twins) and returns the program.
fn plan_pocket(dxf: &Path, under: &Path) -> String {
    std::fs::create_dir_all(under).unwrap();
    let part = under.join("part.dxf");
    std::fs::copy(dxf, &part).unwrap();
    let nc = under.join("part.nc");
    let o = run(&[
        "plan",
        part.to_str().unwrap(),
        "--op",
        "pocket",
        "--tool-diameter",
        "2",
        "--depth",
        "1",
        "--stepdown",
        "1",
        "--post",
        "grbl",
        "-o",
        nc.to_str().unwrap(),
    ]);
    assert!(
        o.status.success(),
        "{}: plan failed: {}",
        dxf.display(),
        stderr(&o)
    );
    std::fs::read_to_string(&nc).unwrap()
}

/// The XY ends of the program's moves below the stock top (modal X, Y, Z words).
fn cutting_points(gcode: &str) -> Vec<Point> {
    let (mut x, mut y, mut z) = (0.0, 0.0, f64::INFINITY);
    let mut out = Vec::new();
    for line in gcode.lines() {
        let line = line.split(['(', ';']).next().unwrap_or("");
        let mut moved = false;
        for w in line.split_whitespace() {
            let (k, v) = w.split_at(1);
            let Ok(v) = v.parse::<f64>() else { continue };
            match k {
                "X" => (x, moved) = (v, true),
                "Y" => (y, moved) = (v, true),
                "Z" => z = v,
                _ => {}
            }
        }
        if moved && z < -1e-9 {
            out.push(Point::new(x, y));
        }
    }
    out
}

#[test]
fn hatch_drawings_pocket_inside_their_hatches_and_binary_twins_plan_the_same() {
    let dir = tempfile::tempdir().unwrap();
    let expected = write_drawings(dir.path());
    for name in expected.as_object().unwrap().keys() {
        let ascii = dir.path().join(format!("{name}.dxf"));
        let program = plan_pocket(&ascii, &dir.path().join("ascii").join(name));
        let twin = plan_pocket(
            &dir.path().join(format!("{name}_bin.dxf")),
            &dir.path().join("bin").join(name),
        );
        assert!(
            program == twin,
            "{name}: the binary DXF plans another program than its ASCII twin"
        );
        let regions = offset_core::io::read_shape(&std::fs::read(&ascii).unwrap(), "part.dxf")
            .unwrap()
            .regions();
        let cuts = cutting_points(&program);
        assert!(
            !cuts.is_empty(),
            "{name}: the pocket cuts nothing:\n{program}"
        );
        for p in cuts {
            assert!(
                regions.iter().any(|r| r.contains(p)),
                "{name}: a cutting move ends at ({}, {}), outside every hatched region",
                p.x,
                p.y
            );
        }
    }
}
