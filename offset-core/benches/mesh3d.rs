//! 3D benchmark: drop-cutter points per second on a 20,000-triangle height field and a
//! 4,000-triangle solid against OpenCAMLib's BatchDropCutter, and the mesh offset's time,
//! output faces and worst error on the solid against MeshLib's offsetMesh — the anchors
//! measured in the same run through `benches/py/anchors.py` (an anchor that cannot run is
//! reported as such).
//! Run: `cargo bench -p offset-core --bench mesh3d` (prints a markdown table).

use offset_core::mesh::offset::{measure_error, offset, MeshOffsetOptions};
use offset_core::mesh::shapes::{height_field, height_field_solid};
use offset_core::mesh::{read_stl, write_stl, Cutter, CutterShape, DropCutter, Mesh};
use std::path::Path;
use std::process::Command;
use std::time::Instant;

fn python() -> String {
    std::env::var("MACHLINK_PYTHON").unwrap_or_else(|_| "python3".into())
}

fn script() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/py/anchors.py")
}

/// Writes `m` as STL and reads it back, so both sides see the same single-precision mesh.
fn via_stl(m: &Mesh, path: &Path) -> Mesh {
    let b = write_stl(m);
    std::fs::write(path, &b).unwrap();
    read_stl(&b, &path.display().to_string(), &Default::default()).unwrap()
}

fn grid_points(m: &Mesh, n: usize) -> Vec<(f64, f64)> {
    let (lo, hi) = m.bounds().unwrap();
    let mut pts = Vec::with_capacity(n * n);
    for j in 0..n {
        for i in 0..n {
            pts.push((
                lo.x + (hi.x - lo.x) * (i as f64 + 0.31) / n as f64,
                lo.y + (hi.y - lo.y) * (j as f64 + 0.47) / n as f64,
            ));
        }
    }
    pts
}

fn best_of(k: usize, mut f: impl FnMut()) -> f64 {
    (0..k)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
}

fn shape_name(c: &Cutter) -> &'static str {
    match c.shape {
        CutterShape::Ball => "ball",
        CutterShape::Flat => "flat",
        CutterShape::Bull => "bull",
    }
}

/// OpenCAMLib over `pts`: (seconds, heights) or why it could not run.
fn ocl(
    stl: &Path,
    pts: &[(f64, f64)],
    min_z: f64,
    c: &Cutter,
) -> Result<(f64, Vec<f64>, u64), String> {
    let dir = stl.parent().unwrap();
    let job = dir.join("pts.json");
    let out = dir.join("ocl.json");
    std::fs::write(
        &job,
        serde_json::json!({"min_z": min_z, "points": pts}).to_string(),
    )
    .unwrap();
    let r = Command::new(python())
        .arg(script())
        .args([
            "ocl",
            &stl.display().to_string(),
            &job.display().to_string(),
            shape_name(c),
        ])
        .arg(c.diameter.to_string())
        .arg(c.corner_radius.to_string())
        .arg(&out)
        .output()
        .map_err(|e| e.to_string())?;
    if !r.status.success() {
        return Err(String::from_utf8_lossy(&r.stderr)
            .lines()
            .last()
            .unwrap_or("failed")
            .to_string());
    }
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    let zs = v["heights"]
        .as_array()
        .unwrap()
        .iter()
        .map(|z| z.as_f64().unwrap())
        .collect();
    Ok((
        v["seconds"].as_f64().unwrap(),
        zs,
        v["threads"].as_u64().unwrap_or(0),
    ))
}

fn main() {
    let quick = std::env::args().any(|a| a == "quick");
    let dir = tempfile::tempdir().unwrap();
    let field = height_field((0.0, 100.0), (0.0, 100.0), 100, 100, |x, y| {
        4.0 * (x / 9.0).sin() * (y / 13.0).cos() + 0.02 * x * y / 10.0
    });
    let solid = height_field_solid((0.0, 60.0), (0.0, 40.0), 42, 42, 0.0, |x, y| {
        10.0 + 3.0 * (x / 7.0).sin() * (y / 5.0).cos()
    });
    let field = via_stl(&field, &dir.path().join("field.stl"));
    let solid = via_stl(&solid, &dir.path().join("solid.stl"));
    println!("| case | implementation | points | time | points/s | worst difference (mm) |");
    println!("|---|---|---:|---:|---:|---:|");
    for (label, m, file) in [
        (
            format!("height field, {} triangles", field.faces.len()),
            &field,
            "field.stl",
        ),
        (
            format!("solid, {} triangles", solid.faces.len()),
            &solid,
            "solid.stl",
        ),
    ] {
        let stl = dir.path().join(file);
        for c in [Cutter::ball(6.0), Cutter::flat(6.0), Cutter::bull(6.0, 1.0)] {
            let dc = DropCutter::new(m, c).unwrap();
            let min_z = m.bounds().unwrap().0.z - 10.0;
            let pts = grid_points(m, if quick { 100 } else { 400 });
            let mut zs = Vec::new();
            let t = best_of(3, || zs = dc.drop_many(&pts, min_z));
            let t1 = best_of(1, || {
                for &(x, y) in &pts {
                    std::hint::black_box(dc.drop(x, y, min_z));
                }
            });
            let name = format!(
                "{label}, {} d{}{}",
                shape_name(&c),
                c.diameter,
                if c.shape == CutterShape::Bull {
                    format!(" r{}", c.corner_radius)
                } else {
                    String::new()
                }
            );
            println!(
                "| {name} | machlink, 2 threads (rayon) | {} | {:.1} ms | {:.0} | |",
                pts.len(),
                t * 1e3,
                pts.len() as f64 / t
            );
            println!(
                "| {name} | machlink, 1 thread | {} | {:.1} ms | {:.0} | |",
                pts.len(),
                t1 * 1e3,
                pts.len() as f64 / t1
            );
            // the anchor on fewer points (it is slow), the same points for both
            let few = grid_points(m, if quick { 20 } else { 40 });
            match ocl(&stl, &few, min_z, &c) {
                Ok((secs, theirs, threads)) => {
                    let ours = dc.drop_many(&few, min_z);
                    let diff = ours
                        .iter()
                        .zip(&theirs)
                        .map(|(a, b)| (a - b).abs())
                        .fold(0.0, f64::max);
                    println!("| {name} | OpenCAMLib BatchDropCutter ({threads} threads) | {} | {:.1} ms | {:.0} | {diff:.1e} |", few.len(), secs * 1e3, few.len() as f64 / secs);
                }
                Err(e) => {
                    println!("| {name} | OpenCAMLib BatchDropCutter | – | could not run: {e} | | |")
                }
            }
            let _ = zs;
        }
    }
    println!();
    println!("| offset of the {}-triangle solid | implementation | distance | tolerance | time | faces out | worst error (mm) |", solid.faces.len());
    println!("|---|---|---:|---:|---:|---:|---:|");
    for d in [1.0, 3.0] {
        for tol in [0.1, 0.05, 0.01] {
            let opts = MeshOffsetOptions { tolerance: tol };
            let mut out = None;
            let t = best_of(5, || out = Some(offset(&solid, d, &opts).unwrap()));
            let out = out.unwrap();
            let (err, _) = measure_error(&solid, &out.mesh, d, 3);
            let closed = if out.mesh.report().closed {
                "closed"
            } else {
                "NOT closed"
            };
            println!("| solid | machlink (multiple normals), {closed} | {d} | {tol} | {:.1} ms | {} | {err:.4} |", t * 1e3, out.mesh.faces.len());
        }
        for voxels in [1e6, 1e7] {
            let out_stl = dir.path().join("ml.stl");
            let out_json = dir.path().join("ml.json");
            let r = Command::new(python())
                .arg(script())
                .args([
                    "meshlib",
                    &dir.path().join("solid.stl").display().to_string(),
                    &d.to_string(),
                    &voxels.to_string(),
                ])
                .arg(&out_stl)
                .arg(&out_json)
                .output();
            match r {
                Ok(o) if o.status.success() => {
                    let v: serde_json::Value =
                        serde_json::from_slice(&std::fs::read(&out_json).unwrap()).unwrap();
                    let theirs = read_stl(
                        &std::fs::read(&out_stl).unwrap(),
                        "meshlib.stl",
                        &Default::default(),
                    )
                    .unwrap();
                    let (err, _) = measure_error(&solid, &theirs, d, 3);
                    println!(
                        "| solid | MeshLib offsetMesh, voxel {:.3} mm (≈{voxels:.0e} voxels) | {d} | | {:.1} ms | {} | {err:.4} |",
                        v["voxel"].as_f64().unwrap_or(0.0),
                        v["seconds"].as_f64().unwrap() * 1e3,
                        v["faces"]
                    );
                }
                Ok(o) => println!(
                    "| solid | MeshLib offsetMesh | {d} | | could not run: {} | | |",
                    String::from_utf8_lossy(&o.stderr)
                        .lines()
                        .last()
                        .unwrap_or("failed")
                ),
                Err(e) => {
                    println!("| solid | MeshLib offsetMesh | {d} | | could not run: {e} | | |")
                }
            }
        }
    }
}
