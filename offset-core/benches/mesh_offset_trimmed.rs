//! The trimmed mesh offset against MeshLib's voxel offsets on the parts whose offsets
//! interfere (a U-channel with a slot narrower than 2d, a stepped block with fillets
//! smaller than d, two cubes sharing a face), grown and shrunk: time, faces out and the
//! worst distance error, each output (ours and MeshLib's, read back from STL) sampled the
//! same way by `mesh::offset::measure_error` against the part's surface. MeshLib runs in
//! the same process run through `benches/py/anchors.py` (an anchor that cannot run is
//! reported as such).
//! Run: `cargo bench -p offset-core --bench mesh_offset_trimmed` (prints a markdown table).

use offset_core::mesh::offset::{measure_error, offset, MeshOffsetOptions, OffsetMethod};
use offset_core::mesh::shapes::{cuboid, filleted_step, touching_cubes, u_channel};
use offset_core::mesh::{read_stl, write_stl, Mesh, V3};
use std::path::Path;
use std::process::Command;
use std::time::Instant;

fn python() -> String {
    std::env::var("MACHLINK_PYTHON").unwrap_or_else(|_| "python3".into())
}

fn script() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/py/anchors.py")
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

/// MeshLib's offset of `stl` by `d` at `voxel` mm: (seconds, faces, the mesh) or why not.
fn meshlib(stl: &Path, d: f64, voxel: f64, mode: &str) -> Result<(f64, u64, Mesh), String> {
    let dir = stl.parent().unwrap();
    let (out_stl, out_json) = (dir.join("ml.stl"), dir.join("ml.json"));
    let o = Command::new(python())
        .arg(script())
        .arg("meshlib_voxel")
        .arg(stl)
        .args([d.to_string(), voxel.to_string(), mode.to_string()])
        .arg(&out_stl)
        .arg(&out_json)
        .output()
        .map_err(|e| e.to_string())?;
    if !o.status.success() {
        return Err(String::from_utf8_lossy(&o.stderr)
            .lines()
            .last()
            .unwrap_or("failed")
            .to_string());
    }
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&out_json).unwrap()).map_err(|e| e.to_string())?;
    let m = read_stl(
        &std::fs::read(&out_stl).unwrap(),
        "meshlib.stl",
        &Default::default(),
    )
    .map_err(|e| e.to_string())?;
    Ok((
        v["seconds"].as_f64().unwrap_or(f64::NAN),
        v["faces"].as_u64().unwrap_or(0),
        m,
    ))
}

fn main() {
    let quick = std::env::args().any(|a| a == "quick");
    let dir = tempfile::tempdir().unwrap();
    // (name, part, the part's surface to measure against, distances)
    let parts: Vec<(&str, Mesh, Mesh, [f64; 2])> = vec![
        {
            let m = u_channel(10.0, 6.0, 2.0, 2.0, 8.0);
            ("U-channel 10×6×8, slot 2", m.clone(), m, [1.5, -1.5])
        },
        {
            let m = filleted_step(12.0, 8.0, 4.0, 0.5, 6, 8.0);
            ("step 12×8×8, fillets r 0.5", m.clone(), m, [1.5, -1.5])
        },
        (
            "two 5 mm cubes sharing a face",
            touching_cubes(5.0, false),
            // the union's surface: one 10 × 5 × 5 box
            cuboid(V3::ZERO, V3::new(10.0, 5.0, 5.0)),
            [1.0, -1.0],
        ),
    ];
    // the multiple-normal offset where nothing interferes, now with its sampled check: the
    // 4032-triangle solid of benches/mesh3d.rs
    let solid = offset_core::mesh::shapes::height_field_solid(
        (0.0, 60.0),
        (0.0, 40.0),
        42,
        42,
        0.0,
        |x, y| 10.0 + 3.0 * (x / 7.0).sin() * (y / 5.0).cos(),
    );
    println!("| part | tolerance | method | time (offset and its sampled check) | faces out |");
    println!("|---|---:|---|---:|---:|");
    for tol in [0.1, 0.01] {
        let opts = MeshOffsetOptions { tolerance: tol };
        let mut out = None;
        let t = best_of(5, || out = Some(offset(&solid, 1.0, &opts).unwrap()));
        let out = out.unwrap();
        println!(
            "| 4032-triangle solid, d 1 | {tol} | {:?} | {:.1} ms | {} |",
            out.report.method,
            t * 1e3,
            out.mesh.faces.len()
        );
    }
    println!();
    println!("| part | d | implementation | time | faces out | worst error (mm) | closed |");
    println!("|---|---:|---|---:|---:|---:|---|");
    for (name, part, surface, ds) in &parts {
        let stl = dir.path().join("part.stl");
        std::fs::write(&stl, write_stl(part)).unwrap();
        for &d in ds {
            for tol in [0.05, 0.02] {
                let opts = MeshOffsetOptions { tolerance: tol };
                let mut out = None;
                let t = best_of(if quick { 1 } else { 3 }, || {
                    out = Some(offset(part, d, &opts).unwrap())
                });
                let out = out.unwrap();
                let (err, _) = measure_error(surface, &out.mesh, d, 3);
                let how = match out.report.method {
                    OffsetMethod::Trimmed => {
                        format!(
                            "machlink trimmed, tolerance {tol} (grid {:.3} mm)",
                            out.report.grid_step
                        )
                    }
                    OffsetMethod::MultipleNormals => {
                        format!("machlink multiple normals, tolerance {tol}")
                    }
                    OffsetMethod::OneSided => {
                        format!(
                            "machlink one-sided, tolerance {tol} (grid {:.3} mm)",
                            out.report.grid_step
                        )
                    }
                };
                println!(
                    "| {name} | {d} | {how} | {:.1} ms | {} | {err:.4} | {} |",
                    t * 1e3,
                    out.mesh.faces.len(),
                    out.mesh.report().closed
                );
            }
            for (mode, voxel) in [
                ("offset", 0.1),
                ("offset", 0.05),
                ("offset", 0.025),
                ("sharp", 0.1),
                ("sharp", 0.05),
            ] {
                let label = if mode == "sharp" {
                    "MeshLib sharpOffsetMesh"
                } else {
                    "MeshLib offsetMesh"
                };
                match meshlib(&stl, d, voxel, mode) {
                    Ok((secs, faces, m)) => {
                        let (err, _) = measure_error(surface, &m, d, 3);
                        println!(
                            "| {name} | {d} | {label}, voxel {voxel} mm | {:.1} ms | {faces} | {err:.4} | {} |",
                            secs * 1e3,
                            m.report().closed
                        );
                    }
                    Err(e) => println!(
                        "| {name} | {d} | {label}, voxel {voxel} mm | could not run: {e} | | | |"
                    ),
                }
            }
        }
    }
}
