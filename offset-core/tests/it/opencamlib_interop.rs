//! Drop-cutter against an implementation this project did not write: OpenCAMLib's
//! `BatchDropCutter` (Python package `opencamlib`, installed by `.ci/run` from
//! `.ci/requirements.txt`) on the same binary STL, for ball, flat and bull cutters; every
//! tool-tip height agrees within 1e-6 mm. The test fails, never skips, when Python or the
//! package is missing. `MACHLINK_PYTHON` names another interpreter (default `python3`).

use offset_core::mesh::shapes::{cube_with_boss, height_field, sphere};
use offset_core::mesh::{read_stl, write_stl, Cutter, CutterShape, DropCutter, Mesh, V3};
use std::path::Path;
use std::process::Command;

const AGREE: f64 = 1e-6;

fn cutters() -> Vec<(&'static str, Cutter)> {
    vec![
        ("ball d6", Cutter::ball(6.0)),
        ("flat d6", Cutter::flat(6.0)),
        ("bull d6 r1", Cutter::bull(6.0, 1.0)),
        ("ball d1.5", Cutter::ball(1.5)),
        ("bull d10 r2.5", Cutter::bull(10.0, 2.5)),
    ]
}

/// OpenCAMLib's heights for each cutter over `pts`, from the STL at `stl`.
fn ocl_heights(stl: &Path, pts: &[(f64, f64)], min_z: f64) -> Vec<Vec<f64>> {
    let dir = stl.parent().unwrap();
    let job = dir.join("job.json");
    let out = dir.join("out.json");
    let cs: Vec<serde_json::Value> = cutters()
        .iter()
        .map(|(name, c)| {
            serde_json::json!({
                "name": name,
                "shape": match c.shape { CutterShape::Ball => "ball", CutterShape::Flat => "flat", CutterShape::Bull => "bull" },
                "diameter": c.diameter,
                "corner_radius": c.corner_radius,
            })
        })
        .collect();
    let body = serde_json::json!({ "min_z": min_z, "points": pts, "cutters": cs });
    std::fs::write(&job, body.to_string()).unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/py/ocl_dropcutter.py");
    let python = std::env::var("MACHLINK_PYTHON").unwrap_or_else(|_| "python3".into());
    let run = Command::new(&python)
        .arg(&script)
        .arg(stl)
        .arg(&job)
        .arg(&out)
        .output()
        .unwrap_or_else(|e| {
            panic!("the OpenCAMLib interop test needs Python 3 (≤ 3.11) with the opencamlib package; `{python}` did not start: {e}")
        });
    if !run.status.success() {
        panic!(
            "the OpenCAMLib interop test needs the Python package opencamlib (pip install -r .ci/requirements.txt); {} exited with {}: {}",
            script.display(),
            run.status,
            String::from_utf8_lossy(&run.stderr).trim()
        );
    }
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    cutters()
        .iter()
        .map(|(name, _)| {
            v["heights"][name]
                .as_array()
                .unwrap_or_else(|| panic!("OpenCAMLib gave no heights for {name}"))
                .iter()
                .map(|z| z.as_f64().unwrap())
                .collect()
        })
        .collect()
}

/// Writes `m` as a binary STL, reads it back (both sides then see the same
/// single-precision corners) and compares every cutter's heights over `pts`.
fn agree(case: &str, m: &Mesh, pts: &[(f64, f64)]) {
    let dir = tempfile::tempdir().unwrap();
    let stl = dir.path().join("part.stl");
    let bytes = write_stl(m);
    std::fs::write(&stl, &bytes).unwrap();
    let ours_mesh = read_stl(&bytes, "part.stl", &Default::default()).unwrap();
    let min_z = ours_mesh.bounds().unwrap().0.z - 10.0;
    let theirs = ocl_heights(&stl, pts, min_z);
    for ((name, c), zs) in cutters().iter().zip(theirs) {
        assert_eq!(
            zs.len(),
            pts.len(),
            "{case}, {name}: OpenCAMLib returned {} points for {}",
            zs.len(),
            pts.len()
        );
        let dc = DropCutter::new(&ours_mesh, *c).unwrap();
        let mut worst = (0.0f64, 0usize);
        for (i, (&(x, y), &z_ocl)) in pts.iter().zip(&zs).enumerate() {
            let z = dc.drop(x, y, min_z);
            let d = (z - z_ocl).abs();
            if d > worst.0 {
                worst = (d, i);
            }
        }
        let (d, i) = worst;
        let touching = zs.iter().filter(|&&z| z > min_z).count();
        eprintln!(
            "{case}, {name}: worst difference {d:.2e} mm over {} points ({touching} touching)",
            pts.len()
        );
        assert!(
            touching * 2 > pts.len(),
            "{case}, {name}: only {touching} of {} points touch the part: the case tests little",
            pts.len()
        );
        assert!(
            d <= AGREE,
            "{case}, {name}: machlink and OpenCAMLib differ by {d:.3e} mm at ({}, {}): {} vs {}",
            pts[i].0,
            pts[i].1,
            dc.drop(pts[i].0, pts[i].1, min_z),
            zs[i]
        );
    }
}

fn grid(lo: V3, hi: V3, n: usize) -> Vec<(f64, f64)> {
    let mut pts = Vec::new();
    for j in 0..n {
        for i in 0..n {
            // a skewed grid: no point sits on a mesh vertex's row or column by design
            let u = (i as f64 + 0.37 * (j % 3) as f64) / (n as f64 - 0.3);
            let v = (j as f64 + 0.21 * (i % 5) as f64) / (n as f64 - 0.1);
            pts.push((lo.x + (hi.x - lo.x) * u, lo.y + (hi.y - lo.y) * v));
        }
    }
    pts
}

#[test]
fn drop_cutter_agrees_with_opencamlib_on_a_wavy_height_field() {
    let m = height_field((0.0, 40.0), (0.0, 30.0), 40, 30, |x, y| {
        3.0 * (x / 5.0).sin() * (y / 7.0).cos() + 0.05 * x
    });
    agree(
        "wavy height field",
        &m,
        &grid(V3::new(-2.0, -2.0, 0.0), V3::new(42.0, 32.0, 0.0), 40),
    );
}

#[test]
fn drop_cutter_agrees_with_opencamlib_on_a_cube_with_a_boss() {
    let m = cube_with_boss(30.0, 7.0, 8.0, 48);
    agree(
        "cube with boss",
        &m,
        &grid(V3::new(-4.0, -4.0, 0.0), V3::new(34.0, 34.0, 0.0), 40),
    );
}

#[test]
fn drop_cutter_agrees_with_opencamlib_on_a_sphere() {
    let m = sphere(V3::new(0.0, 0.0, 0.0), 15.0, 24, 48);
    agree(
        "sphere r15",
        &m,
        &grid(V3::new(-19.0, -19.0, 0.0), V3::new(19.0, 19.0, 0.0), 40),
    );
}
