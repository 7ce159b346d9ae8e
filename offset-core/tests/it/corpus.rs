//! The corpus: real files other software wrote, planned as a user would. Every STL, SVG and
//! DXF of PyCAM 0.6.4's source distribution (PyPI; `.ci/run` unpacks it into
//! target/corpus) and every DXF of shared/data/dxf: meshes get rough3d, finish3d with a
//! ball, a flat and a bull cutter, and a ball waterline; drawings get a profile and a
//! pocket. Each operation plans, or is refused with one sentence naming the file; nothing
//! panics. Every 3D result is checked against OpenCAMLib's drop-cutter on the same
//! triangles: finishing and waterline points never lower than its cutter location by more
//! than the tolerance, and every roughing position at least the allowance off the part
//! (OpenCAMLib's bull cutter of the tool grown by the allowance). The test prints the
//! table of docs/3d.md and docs/toolpaths.md (file, faces or entities, operation, result,
//! time) and writes it to target/corpus/table.md. It fails, naming what is missing, when
//! the corpus, Python or opencamlib is absent.

use offset_core::io::{read_shape_with, ReadOptions};
use offset_core::mesh::{
    finish3d, read_stl, rough3d, rough3d_safe_links, waterline3d, write_stl, Cutter, CutterShape,
    Finish3dParams, Mesh, Rough3dParams, WaterlineParams,
};
use offset_core::ops::{pocket, profile, PocketParams, ProfileParams, Stepover};
use offset_core::toolpath::{Move, Tool, Toolpath, P3};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

const TOL: f64 = 0.02;
const ROUGH_TOL: f64 = 0.1;
const ALLOWANCE: f64 = 0.3;
/// The most points of one result sent to OpenCAMLib (evenly spread over the path).
const CHECK_POINTS: usize = 3000;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn pycam_samples() -> PathBuf {
    let dir = std::env::var_os("MACHLINK_CORPUS")
        .map(PathBuf::from)
        .unwrap_or_else(|| root().join("target/corpus/pycam-0.6.4"))
        .join("samples");
    assert!(
        dir.is_dir(),
        "the corpus test needs PyCAM's sample files in {}: run `pip download pycam==0.6.4 --no-deps --no-binary :all: -d target/corpus && tar -xzf target/corpus/pycam-0.6.4.tar.gz -C target/corpus` (as .ci/run does)",
        dir.display()
    );
    dir
}

fn shared_dxf() -> PathBuf {
    let dir = root().join("../shared/data/dxf");
    assert!(
        dir.is_dir(),
        "the corpus test needs shared/data/dxf beside the repository ({})",
        dir.display()
    );
    dir
}

fn files(dir: &Path, exts: &[&str]) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| {
            p.extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| exts.contains(&e.to_ascii_lowercase().as_str()))
        })
        .collect();
    v.sort();
    v
}

/// One row of the table.
struct Row {
    file: String,
    size: String,
    op: String,
    result: String,
    ms: f64,
}

fn cut_summary(tp: &Toolpath) -> String {
    let cuts = tp
        .moves
        .iter()
        .filter(|m| matches!(m, Move::Linear { .. } | Move::Arc { .. }))
        .count();
    let mut s = format!("{cuts} cutting moves");
    if !tp.warnings.is_empty() {
        s.push_str(&format!(" — warning: {}", tp.warnings.join(" / ")));
    }
    s
}

/// A 3D job to check against OpenCAMLib: the cutter it is judged with, the points
/// (x, y, tip z) and how far below the cutter location a point may lie.
struct Check {
    name: String,
    cutter: Cutter,
    pts: Vec<P3>,
    /// the height above OpenCAMLib's location each point must keep (the allowance)
    above: f64,
    /// how far below that a point may lie (the tolerance)
    slack: f64,
    /// for each point, the point moved the slack sideways out of the part (waterlines,
    /// where the gouge is measured square to a wall: a point passes when either does)
    out: Vec<P3>,
}

fn spread(pts: Vec<P3>) -> Vec<P3> {
    if pts.len() <= CHECK_POINTS {
        return pts;
    }
    let k = pts.len() as f64 / CHECK_POINTS as f64;
    (0..CHECK_POINTS)
        .map(|i| pts[(i as f64 * k) as usize])
        .collect()
}

/// The points a cutting move passes through, every `step` mm, that lie below `safe`.
fn cutting_points(tp: &Toolpath, step: f64, safe: f64) -> Vec<P3> {
    let mut pts = Vec::new();
    tp.walk(P3::new(0.0, 0.0, safe + 100.0), |from, m, _| {
        if matches!(m, Move::Linear { .. } | Move::Arc { .. }) {
            let mut one = Toolpath::new("move");
            one.push(m.clone());
            pts.extend(one.sample(from, step).into_iter().filter(|p| p.z < safe));
        }
    });
    pts
}

/// Each check's name, its worst shortfall against OpenCAMLib (mm a point lies below its
/// location plus the allowance) and the slack it may use.
fn ocl_check(case: &str, m: &Mesh, checks: &[Check]) -> Vec<(String, f64, f64)> {
    // OpenCAMLib's batch drop-cutter crashes on an empty batch
    let checks: Vec<&Check> = checks.iter().filter(|c| !c.pts.is_empty()).collect();
    if checks.is_empty() {
        return Vec::new();
    }
    let dir = tempfile::tempdir().unwrap();
    let stl = dir.path().join("part.stl");
    std::fs::write(&stl, write_stl(m)).unwrap();
    let min_z = m.bounds().unwrap().0.z - 50.0;
    let jobs: Vec<serde_json::Value> = checks
        .iter()
        .map(|c| {
            serde_json::json!({
                "name": c.name,
                "shape": match c.cutter.shape { CutterShape::Ball => "ball", CutterShape::Flat => "flat", CutterShape::Bull => "bull" },
                "diameter": c.cutter.diameter,
                "corner_radius": c.cutter.corner_radius,
                "points": c.pts.iter().chain(&c.out).map(|p| [p.x, p.y]).collect::<Vec<_>>(),
            })
        })
        .collect();
    let job = dir.path().join("job.json");
    let out = dir.path().join("out.json");
    std::fs::write(
        &job,
        serde_json::json!({"min_z": min_z, "jobs": jobs}).to_string(),
    )
    .unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/py/ocl_heights.py");
    let python = std::env::var("MACHLINK_PYTHON").unwrap_or_else(|_| "python3".into());
    let run = Command::new(&python)
        .args([&script, &stl, &job, &out])
        .output()
        .unwrap_or_else(|e| {
            panic!("the corpus test needs Python 3 with opencamlib; `{python}` did not start: {e}")
        });
    assert!(
        run.status.success(),
        "{case}: the corpus test needs the Python package opencamlib (pip install -r .ci/requirements.txt); {} exited with {}: {}",
        script.display(),
        run.status,
        String::from_utf8_lossy(&run.stderr).trim()
    );
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    checks
        .iter()
        .map(|c| {
            let zs = v["heights"][&c.name].as_array().unwrap();
            assert_eq!(
                zs.len(),
                c.pts.len() + c.out.len(),
                "{case}, {}: OpenCAMLib's answer",
                c.name
            );
            let mut worst = f64::NEG_INFINITY;
            let mut at = (P3::default(), 0.0);
            let n = c.pts.len();
            for (i, (p, z)) in c.pts.iter().zip(zs).enumerate() {
                let mut short = z.as_f64().unwrap() + c.above - p.z;
                if i < c.out.len() {
                    short = short.min(zs[n + i].as_f64().unwrap() + c.above - p.z);
                }
                if short > worst {
                    worst = short;
                    at = (*p, z.as_f64().unwrap());
                }
            }
            if worst > c.slack {
                let ours = offset_core::mesh::DropCutter::new(m, c.cutter)
                    .unwrap()
                    .drop(at.0.x, at.0.y, min_z);
                eprintln!(
                    "{case}, {}: at {:?} OpenCAMLib's cutter location is Z {}, ours Z {ours}",
                    c.name, at.0, at.1
                );
            }
            (c.name.clone(), worst, c.slack)
        })
        .collect()
}

fn mesh_rows(path: &Path, rows: &mut Vec<Row>) {
    let file = path.file_name().unwrap().to_string_lossy().into_owned();
    let bytes = std::fs::read(path).unwrap();
    let t = Instant::now();
    let m = match read_stl(&bytes, &file, &Default::default()) {
        Ok(m) => m,
        Err(e) => {
            rows.push(Row {
                file,
                size: "-".into(),
                op: "read".into(),
                result: format!("refused: {e}"),
                ms: t.elapsed().as_secs_f64() * 1e3,
            });
            return;
        }
    };
    let size = format!("{} faces", m.faces.len());
    let top = m.bounds().unwrap().1.z;
    let safe = top + 5.0 - 1e-6;
    let mut checks = Vec::new();
    let push = |op: String, r: Result<Toolpath, String>, ms: f64, rows: &mut Vec<Row>| {
        let result = match &r {
            Ok(tp) => cut_summary(tp),
            Err(e) => {
                assert!(
                    e.contains(&file) && !e.contains('\n'),
                    "{file}, {op}: a refusal names the file in one sentence: {e}"
                );
                format!("refused: {e}")
            }
        };
        rows.push(Row {
            file: file.clone(),
            size: size.clone(),
            op,
            result,
            ms,
        });
        r.ok()
    };

    // rough3d: a flat d6, a 2 mm stock margin
    let rp = Rough3dParams {
        tool: Tool::flat(6.0),
        stepdown: 2.0,
        stepover: Stepover::Percent(45.0),
        stock_allowance: ALLOWANCE,
        stock_margin: 2.0,
        tolerance: ROUGH_TOL,
        ..Default::default()
    };
    let t = Instant::now();
    let r = rough3d(&m, &rp).map_err(|e| e.to_string());
    let ms = t.elapsed().as_secs_f64() * 1e3;
    if let Some(tp) = push("rough3d flat d6".into(), r, ms, rows) {
        // links at depth: the retracts against the rough with every link at the safe height
        if let Ok(safe_links) = rough3d_safe_links(&m, &rp) {
            let (low, high) = (
                offset_core::cutsim::retracts(&tp),
                offset_core::cutsim::retracts(&safe_links),
            );
            eprintln!("{file}, rough3d: {high} retracts with every link at the safe height, {low} with links at depth");
            assert!(
                low <= high,
                "{file}: links at depth retract more ({low}) than safe links ({high})"
            );
        }
        // the tool grown by a ball of the allowance: a bull of radius r + a, corner a; judged
        // a micrometre short of it (a tool whose rim stands exactly the allowance off a
        // wall does not cut it, but a drop-cutter height there jumps)
        let a = ALLOWANCE - 1e-3;
        checks.push(Check {
            name: "rough3d".into(),
            cutter: Cutter::bull(6.0 + 2.0 * a, a),
            pts: spread(cutting_points(&tp, 0.5, safe)),
            above: a,
            slack: 1e-6,
            out: Vec::new(),
        });
    }
    for (name, c) in [
        ("ball d6", Cutter::ball(6.0)),
        ("flat d6", Cutter::flat(6.0)),
        ("bull d6 r1", Cutter::bull(6.0, 1.0)),
    ] {
        let fp = Finish3dParams {
            cutter: c,
            stepover: Stepover::Mm(1.5),
            tolerance: TOL,
            ..Default::default()
        };
        let t = Instant::now();
        let r = finish3d(&m, &fp).map_err(|e| e.to_string());
        let ms = t.elapsed().as_secs_f64() * 1e3;
        if let Some(tp) = push(format!("finish3d {name}"), r, ms, rows) {
            // the cutter locations themselves are drop-cutter heights: no lower than
            // OpenCAMLib's, within the tolerance
            let pts: Vec<P3> = tp
                .moves
                .iter()
                .filter_map(|mv| match mv {
                    Move::Linear { to, .. } if to.z < safe => Some(*to),
                    _ => None,
                })
                .collect();
            checks.push(Check {
                name: format!("finish3d {name}"),
                cutter: c,
                pts: spread(pts),
                above: 0.0,
                slack: TOL,
                out: Vec::new(),
            });
        }
    }
    let wp = WaterlineParams {
        cutter: Cutter::ball(6.0),
        stepdown: 1.0,
        tolerance: TOL,
        ..Default::default()
    };
    let t = Instant::now();
    let r = waterline3d(&m, &wp).map_err(|e| e.to_string());
    let ms = t.elapsed().as_secs_f64() * 1e3;
    if let Some(tp) = push("waterline ball d6".into(), r, ms, rows) {
        // the contour vertices, each also moved the tolerance out of the part (climb runs
        // clockwise round material: out is to the left), since at a wall a ball's equator
        // touches exactly where the drop-cutter height jumps
        let mut pts = Vec::new();
        let mut out = Vec::new();
        tp.walk(P3::new(0.0, 0.0, safe + 100.0), |from, mv, to| {
            if let Move::Linear { .. } = mv {
                if to.z < safe {
                    let (dx, dy) = (to.x - from.x, to.y - from.y);
                    let l = dx.hypot(dy);
                    let (nx, ny) = if l > 1e-12 {
                        (-dy / l, dx / l)
                    } else {
                        (0.0, 0.0)
                    };
                    pts.push(to);
                    out.push(P3::new(to.x + nx * TOL, to.y + ny * TOL, to.z));
                }
            }
        });
        let (pts, out) = if pts.len() > CHECK_POINTS {
            (spread(pts), spread(out))
        } else {
            (pts, out)
        };
        checks.push(Check {
            name: "waterline".into(),
            cutter: wp.cutter,
            pts,
            above: 0.0,
            slack: TOL,
            out,
        });
    }
    for (name, worst, slack) in ocl_check(&file, &m, &checks) {
        eprintln!("{file}, {name}: worst {worst:.6} mm below OpenCAMLib's cutter location (allowed {slack})");
        assert!(
            worst <= slack,
            "{file}, {name}: a point lies {worst:.5} mm too low against OpenCAMLib's drop-cutter (a gouge; allowed {slack})"
        );
    }
}

fn drawing_rows(path: &Path, rows: &mut Vec<Row>) {
    let file = path.file_name().unwrap().to_string_lossy().into_owned();
    let bytes = std::fs::read(path).unwrap();
    let read = read_shape_with(
        &bytes,
        &file,
        &ReadOptions {
            layers: Vec::new(),
            colors: Vec::new(),
            tolerance: 0.01,
        },
    );
    let (shape, warnings) = match read {
        Ok(x) => x,
        Err(e) => {
            let e = e.to_string();
            assert!(!e.contains('\n'), "{file}: one sentence: {e}");
            rows.push(Row {
                file,
                size: "-".into(),
                op: "read".into(),
                result: format!("refused: {e}"),
                ms: 0.0,
            });
            return;
        }
    };
    let closed = shape.paths.iter().filter(|p| p.closed).count();
    let size = format!(
        "{} paths ({closed} closed){}",
        shape.paths.len(),
        if warnings.is_empty() {
            String::new()
        } else {
            format!(", {} reader warnings", warnings.len())
        }
    );
    let mut pp = ProfileParams::default();
    pp.cut.tool = Tool::flat(1.0);
    pp.cut.depth = 1.0;
    pp.cut.tolerance = 0.01;
    let t = Instant::now();
    let r = profile(&shape, &pp);
    let ms = t.elapsed().as_secs_f64() * 1e3;
    rows.push(Row {
        file: file.clone(),
        size: size.clone(),
        op: "profile d1".into(),
        result: match r {
            Ok(tp) => cut_summary(&tp),
            Err(e) => format!("refused: {e}"),
        },
        ms,
    });
    let mut kp = PocketParams::default();
    kp.cut.tool = Tool::flat(1.0);
    kp.cut.depth = 1.0;
    kp.cut.tolerance = 0.01;
    let t = Instant::now();
    let r = pocket(&shape, &kp);
    let ms = t.elapsed().as_secs_f64() * 1e3;
    rows.push(Row {
        file,
        size,
        op: "pocket d1".into(),
        result: match r {
            Ok(tp) => cut_summary(&tp),
            Err(e) => format!("refused: {e}"),
        },
        ms,
    });
}

fn table(rows: &[Row]) -> String {
    let mut s = String::from(
        "| file | faces / paths | operation | result | time, ms |\n|---|---|---|---|---|\n",
    );
    for r in rows {
        s.push_str(&format!(
            "| {} | {} | {} | {} | {:.0} |\n",
            r.file,
            r.size,
            r.op,
            r.result.replace('|', "\\|"),
            r.ms
        ));
    }
    s
}

#[test]
fn every_mesh_of_the_corpus_plans_all_3d_operations_without_gouging() {
    let dir = pycam_samples();
    let stls = files(&dir, &["stl"]);
    assert_eq!(
        stls.len(),
        15,
        "PyCAM 0.6.4's samples hold 15 STL files: {stls:?}"
    );
    let mut rows = Vec::new();
    for f in &stls {
        mesh_rows(f, &mut rows);
    }
    let t = table(&rows);
    eprintln!("{t}");
    std::fs::create_dir_all(root().join("target/corpus")).unwrap();
    std::fs::write(root().join("target/corpus/meshes.md"), &t).unwrap();
    // every mesh reads, and finishing plans on every one
    for r in &rows {
        assert!(r.op != "read", "{}: {}", r.file, r.result);
        if r.op.starts_with("finish3d") {
            assert!(
                !r.result.starts_with("refused"),
                "{} {}: {}",
                r.file,
                r.op,
                r.result
            );
        }
    }
}

#[test]
fn every_drawing_of_the_corpus_plans_or_is_refused_in_a_sentence() {
    let mut paths = files(&pycam_samples(), &["svg", "dxf"]);
    assert_eq!(
        paths.len(),
        9,
        "PyCAM 0.6.4's samples hold 8 SVG and 1 DXF: {paths:?}"
    );
    paths.extend(files(&shared_dxf(), &["dxf"]));
    let mut rows = Vec::new();
    for f in &paths {
        drawing_rows(f, &mut rows);
    }
    let t = table(&rows);
    eprintln!("{t}");
    std::fs::create_dir_all(root().join("target/corpus")).unwrap();
    std::fs::write(root().join("target/corpus/drawings.md"), &t).unwrap();
    // a refusal is one sentence (the operations name the path and the point; the daemon
    // puts the file before it)
    for r in &rows {
        if let Some(e) = r.result.strip_prefix("refused: ") {
            assert!(
                !e.contains('\n') && e.len() > 20,
                "{} {}: {e}",
                r.file,
                r.op
            );
        }
    }
}
