//! 3D jobs through the `machlink` binary, checked against the exact part they were made
//! from: a spherical cap (radius 40, 10 mm high) standing on a plate, as an STL file and as
//! a grid of measured points. The programs are read back from their G-code.

use crate::common;
use common::cli::{ok, run as machlink};

use offset_core::mesh::{shapes, write_stl};
use offset_core::toolpath::{Move, Toolpath, P3};
use std::path::Path;

const R: f64 = 40.0;
/// The cap's top is 10 mm above the plate: its centre is 30 mm below the plate.
const SINK: f64 = 30.0;

/// Height of the part at distance `rho` from the cap's axis.
fn part_z(rho: f64) -> f64 {
    if rho < R {
        ((R * R - rho * rho).sqrt() - SINK).max(0.0)
    } else {
        0.0
    }
}

/// The cap on a 80 × 80 mm plate as a solid of 1 mm cells, down to Z = -10, as binary STL.
fn write_part(dir: &Path) -> String {
    let m = shapes::height_field_solid((-40.0, 40.0), (-40.0, 40.0), 80, 80, -10.0, |x, y| {
        part_z(x.hypot(y))
    });
    let p = dir.join("cap.stl");
    std::fs::write(&p, write_stl(&m)).unwrap();
    p.display().to_string()
}

fn read_program(path: &Path) -> Toolpath {
    machlink_protocols::gcode_read::read(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// Every point a cutting move passes through, every 0.25 mm (arcs followed as arcs).
fn cutting_points(tp: &Toolpath) -> Vec<P3> {
    let mut pts = Vec::new();
    tp.walk(P3::default(), |from, m, _| {
        if matches!(m, Move::Linear { .. } | Move::Arc { .. }) {
            let mut one = Toolpath::new("move");
            one.push(m.clone());
            pts.extend(one.sample(from, 0.25));
        }
    });
    pts
}

/// The ball cutter's tip height over the cap where it touches only the sphere.
fn ball_tip_on_sphere(rho: f64, r: f64) -> f64 {
    ((R + r).powi(2) - rho * rho).sqrt() - SINK - r
}

#[test]
fn finishing_an_stl_with_a_ball_follows_the_exact_cap() {
    let dir = tempfile::tempdir().unwrap();
    let stl = write_part(dir.path());
    let out = dir.path().join("finish.nc");
    let o = machlink(&[
        "plan",
        &stl,
        "--op",
        "finish3d",
        "--cutter",
        "ball",
        "--tool-diameter",
        "6",
        "--stepover",
        "2",
        "--tolerance",
        "0.01",
        "--post",
        "grbl",
        "-o",
        out.to_str().unwrap(),
    ]);
    ok(&o, "plan finish3d");
    let pts = cutting_points(&read_program(&out));
    let mut checked = 0;
    for p in &pts {
        let rho = p.x.hypot(p.y);
        if rho < 20.0 {
            // inside the cap the ball touches the sphere only; the 1 mm facets lie within
            // 0.01 mm of it, the fitting within 0.01 mm of the facets
            let exact = ball_tip_on_sphere(rho, 3.0);
            assert!(
                (p.z - exact).abs() < 0.03,
                "at ({:.2}, {:.2}) the tip is at {:.4}, the exact ball over the cap at {exact:.4}",
                p.x,
                p.y,
                p.z
            );
            checked += 1;
        }
    }
    assert!(checked > 1000, "only {checked} points over the cap");
}

#[test]
fn roughing_an_stl_leaves_the_allowance_everywhere() {
    let dir = tempfile::tempdir().unwrap();
    let stl = write_part(dir.path());
    let out = dir.path().join("rough.nc");
    let o = machlink(&[
        "plan",
        &stl,
        "--op",
        "rough3d",
        "--tool-diameter",
        "6",
        "--stepdown",
        "2",
        "--stepover",
        "40%",
        "--stock-allowance",
        "0.5",
        "--stock-margin",
        "5",
        "--post",
        "grbl",
        "-o",
        out.to_str().unwrap(),
    ]);
    ok(&o, "plan rough3d");
    // the plan's figures count the retracts (links at depth make them fewer)
    let said = String::from_utf8_lossy(&o.stderr);
    assert!(
        said.contains(" retracts to the safe height"),
        "no retract count in {said}"
    );
    let pts = cutting_points(&read_program(&out));
    assert!(pts.len() > 100, "{} cutting points", pts.len());
    let levels: std::collections::BTreeSet<i64> =
        pts.iter().map(|p| (p.z * 1000.0).round() as i64).collect();
    assert!(levels.len() >= 5, "levels {levels:?}");
    for p in &pts {
        // the part is the square block |x|, |y| <= 40: a tool of radius 3 whose footprint
        // misses it has nothing under it
        let (dx, dy) = ((p.x.abs() - 40.0).max(0.0), (p.y.abs() - 40.0).max(0.0));
        if dx.hypot(dy) > 3.0 {
            continue;
        }
        // a flat end mill of radius 3 stands on the highest point of the part under it
        let rho = p.x.hypot(p.y);
        let under = part_z((rho - 3.0).max(0.0));
        assert!(
            p.z >= under + 0.5 - 0.02,
            "at ({:.2}, {:.2}, {:.3}) the tool is {:.3} mm above the part (allowance 0.5)",
            p.x,
            p.y,
            p.z,
            p.z - under
        );
    }
}

#[test]
fn a_point_grid_is_fitted_and_finished_like_the_part_it_measures() {
    let dir = tempfile::tempdir().unwrap();
    let mut csv = String::from("x,y,z\n");
    for j in 0..=20 {
        for i in 0..=20 {
            let (x, y) = (-20.0 + 2.0 * i as f64, -20.0 + 2.0 * j as f64);
            csv.push_str(&format!("{x},{y},{:.6}\n", part_z(x.hypot(y))));
        }
    }
    let grid = dir.path().join("probed.csv");
    std::fs::write(&grid, csv).unwrap();
    let out = dir.path().join("probed.nc");
    let o = machlink(&[
        "plan",
        grid.to_str().unwrap(),
        "--op",
        "finish3d",
        "--tool-diameter",
        "6",
        "--stepover",
        "1.5",
        "--tolerance",
        "0.01",
        "-o",
        out.to_str().unwrap(),
    ]);
    ok(&o, "plan finish3d on a point grid");
    let pts = cutting_points(&read_program(&out));
    let mut checked = 0;
    for p in pts.iter().filter(|p| p.x.hypot(p.y) < 10.0) {
        let exact = ball_tip_on_sphere(p.x.hypot(p.y), 3.0);
        assert!(
            (p.z - exact).abs() < 0.03,
            "at ({:.2}, {:.2}) {:.4} against {exact:.4}",
            p.x,
            p.y,
            p.z
        );
        checked += 1;
    }
    assert!(checked > 200, "{checked} points checked");
}

#[test]
fn offset_of_an_stl_reports_faces_and_its_worst_error() {
    let dir = tempfile::tempdir().unwrap();
    let stl = write_part(dir.path());
    let out = dir.path().join("grown.stl");
    let o = machlink(&[
        "offset",
        &stl,
        "--distance",
        "1",
        "--tolerance",
        "0.05",
        "-o",
        out.to_str().unwrap(),
    ]);
    ok(&o, "offset an STL");
    let said = String::from_utf8_lossy(&o.stderr);
    assert!(
        said.contains("faces in") && said.contains("worst distance error"),
        "{said}"
    );
    let grown = offset_core::mesh::read_stl(
        &std::fs::read(&out).unwrap(),
        "grown.stl",
        &Default::default(),
    )
    .unwrap();
    // every vertex of the grown part is 1 mm outside the part: over the cap's top, 1 mm
    // above the sphere
    let (lo, hi) = grown.bounds().unwrap();
    assert!((hi.z - 11.0).abs() < 0.06, "top at {}", hi.z);
    assert!((lo.z + 11.0).abs() < 0.06, "bottom at {}", lo.z);
    // a mesh offset written as anything but STL is refused in a sentence
    let o = machlink(&["offset", &stl, "--distance", "1", "-o", "grown.json"]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("write it to a .stl file"));
}

#[test]
fn a_3d_plan_is_previewed_over_the_shaded_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let stl = write_part(dir.path());
    let svg = dir.path().join("finish.svg");
    let o = machlink(&[
        "preview",
        &stl,
        "--op",
        "finish3d",
        "--stepover",
        "4",
        "-o",
        svg.to_str().unwrap(),
    ]);
    ok(&o, "preview a 3D plan");
    let text = std::fs::read_to_string(&svg).unwrap();
    assert!(
        text.contains("<polygon") && text.contains("<path"),
        "mesh faces and a path"
    );
    // a 2D operation on a mesh is refused naming the file
    let o = machlink(&["plan", &stl, "--op", "pocket", "-o", "x.nc"]);
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        e.contains("cap.stl is a mesh") && e.contains("rough3d"),
        "{e}"
    );
}

/// Two blocks 5 mm high whose walls come within 1 mm of each other at the top (a V groove
/// between them, as a height field of 0.5 mm cells makes it). Grown by the allowance, the
/// sections of the two blocks overlap at every level: the rough must treat them as one
/// island (grown alone, each block's section crossed the other's and the plan was refused),
/// and still keep the allowance from both.
#[test]
fn roughing_blocks_whose_allowances_overlap_keeps_it_from_both() {
    use offset_core::mesh::dropcutter::{Cutter, DropCutter};
    let dir = tempfile::tempdir().unwrap();
    let block = |x: f64, y: f64| {
        if y.abs() <= 15.0 && (0.5..=20.0).contains(&x.abs()) {
            5.0
        } else {
            0.0
        }
    };
    let m = shapes::height_field_solid((-30.0, 30.0), (-25.0, 25.0), 120, 100, -5.0, block);
    let stl = dir.path().join("blocks.stl");
    std::fs::write(&stl, write_stl(&m)).unwrap();
    let out = dir.path().join("rough.nc");
    let o = machlink(&[
        "plan",
        stl.to_str().unwrap(),
        "--op",
        "rough3d",
        "--tool-diameter",
        "6",
        "--stepdown",
        "1",
        "--stock-allowance",
        "0.5",
        "--stock-margin",
        "4",
        "--post",
        "grbl",
        "-o",
        out.to_str().unwrap(),
    ]);
    ok(&o, "plan rough3d of two close blocks");
    let pts = cutting_points(&read_program(&out));
    let levels: std::collections::BTreeSet<i64> =
        pts.iter().map(|p| (p.z * 1000.0).round() as i64).collect();
    assert!(levels.len() >= 4, "levels {levels:?}");
    // the tool widened by the allowance (less the check's slack, so a wall exactly the
    // allowance away is not counted) finds no material above its level (the allowance kept
    // sideways), and the tool itself stands the allowance above what is under it
    let wide = DropCutter::new(&m, Cutter::flat(7.0 - 2.0 * 0.02)).unwrap();
    let tool = DropCutter::new(&m, Cutter::flat(6.0)).unwrap();
    // (a cutter with nothing under it drops to the lowest Z it is given)
    let nothing = -1e6;
    let mut over_the_part = 0;
    for p in &pts {
        let side = wide.drop(p.x, p.y, nothing);
        assert!(
            side <= p.z + 0.02,
            "at ({:.2}, {:.2}, {:.3}) material stands {:.3} mm above the cut within the allowance",
            p.x,
            p.y,
            p.z,
            side - p.z
        );
        let under = tool.drop(p.x, p.y, nothing);
        if under == nothing {
            continue;
        }
        over_the_part += 1;
        assert!(
            p.z >= under + 0.5 - 0.02,
            "at ({:.2}, {:.2}, {:.3}) the tool is {:.3} mm above the part (allowance 0.5)",
            p.x,
            p.y,
            p.z,
            p.z - under
        );
    }
    assert!(
        over_the_part > 500,
        "only {over_the_part} cutting points over the part"
    );
}

/// `machlink offset` on a mesh whose offsets interfere: a U-channel with a 2 mm slot grown
/// by 1.5 mm and shrunk by 1.5 mm, written as STL by the binary and read back. Each result
/// is closed and manifold, no two faces cross and every sampled point is 1.5 mm from the
/// channel within the tolerance (testkit/src/mesh_check.rs, independent of the library).
#[test]
fn offset_of_a_u_channel_narrower_than_2d_is_a_valid_solid_at_the_distance() {
    use common::mesh_check as mc;
    let dir = tempfile::tempdir().unwrap();
    let part = shapes::u_channel(10.0, 6.0, 2.0, 2.0, 8.0);
    let stl = dir.path().join("channel.stl");
    std::fs::write(&stl, write_stl(&part)).unwrap();
    let part_tris: Vec<[mc::P; 3]> = part
        .triangles()
        .map(|t| t.map(|p| [p.x as f32 as f64, p.y as f32 as f64, p.z as f32 as f64]))
        .collect();
    for d in ["1.5", "-1.5"] {
        let out = dir.path().join(format!("channel{d}.stl"));
        let o = machlink(&[
            "offset",
            stl.to_str().unwrap(),
            "--distance",
            d,
            "--tolerance",
            "0.1",
            "-o",
            out.to_str().unwrap(),
        ]);
        ok(&o, "offset a U-channel");
        let said = String::from_utf8_lossy(&o.stderr);
        assert!(
            said.contains("trimmed") && said.contains("faces out"),
            "{said}"
        );
        let m =
            offset_core::mesh::read_stl(&std::fs::read(&out).unwrap(), "out", &Default::default())
                .unwrap();
        let v: Vec<mc::P> = m.vertices.iter().map(|p| [p.x, p.y, p.z]).collect();
        let f: Vec<[usize; 3]> = m.faces.iter().map(|f| f.map(|i| i as usize)).collect();
        if let Err(e) = mc::closed_manifold(&f) {
            panic!("offset by {d} read back: {e}");
        }
        let crossing = mc::self_intersections(&v, &f, 3);
        assert!(
            crossing.is_empty(),
            "offset by {d}: faces {crossing:?} cross"
        );
        let dist: f64 = d.parse().unwrap();
        let (err, at) = mc::worst_distance_error(&part_tris, &v, &f, dist);
        // the STL's single-precision corners add a few microns
        assert!(
            err <= 0.1 + 1e-4,
            "offset by {d}: {at:?} is {err:.4} mm off"
        );
        assert_eq!(
            mc::inside(&part_tris, v[0]),
            dist < 0.0,
            "offset by {d} on the wrong side"
        );
    }
}

/// `machlink offset` on an open surface (a height-field patch, no solid): the binary says in
/// one line that the input is open and the result one-sided, and the STL it writes, read
/// back, is open, has no two faces crossing, and every sampled point is 1 mm from the patch
/// within the tolerance, on the side its normals point to (up) for +1 and below for -1
/// (testkit/src/mesh_check.rs, independent of the library).
#[test]
fn offset_of_an_open_surface_is_one_sided_at_the_distance() {
    use common::mesh_check as mc;
    let dir = tempfile::tempdir().unwrap();
    let wave = |x: f64, y: f64| 2.0 + 0.8 * (x / 3.0).sin() * (y / 4.0).cos();
    let patch = shapes::height_field((0.0, 12.0), (0.0, 10.0), 24, 20, wave);
    let stl = dir.path().join("patch.stl");
    std::fs::write(&stl, write_stl(&patch)).unwrap();
    let part_tris: Vec<[mc::P; 3]> = patch
        .triangles()
        .map(|t| t.map(|p| [p.x as f32 as f64, p.y as f32 as f64, p.z as f32 as f64]))
        .collect();
    for d in ["1", "-1"] {
        let out = dir.path().join(format!("patch{d}.stl"));
        let o = machlink(&[
            "offset",
            stl.to_str().unwrap(),
            "--distance",
            d,
            "--tolerance",
            "0.08",
            "-o",
            out.to_str().unwrap(),
        ]);
        ok(&o, "offset an open patch");
        let said = String::from_utf8_lossy(&o.stderr);
        assert_eq!(said.lines().count(), 1, "{said}");
        assert!(
            said.contains("one-sided: the input is open") && said.contains("faces out"),
            "{said}"
        );
        let m =
            offset_core::mesh::read_stl(&std::fs::read(&out).unwrap(), "out", &Default::default())
                .unwrap();
        let v: Vec<mc::P> = m.vertices.iter().map(|p| [p.x, p.y, p.z]).collect();
        let f: Vec<[usize; 3]> = m.faces.iter().map(|f| f.map(|i| i as usize)).collect();
        assert!(mc::closed_manifold(&f).is_err(), "offset by {d}: open");
        let crossing = mc::self_intersections(&v, &f, 3);
        assert!(
            crossing.is_empty(),
            "offset by {d}: faces {crossing:?} cross"
        );
        let dist: f64 = d.parse().unwrap();
        let (err, at) = mc::worst_distance_error(&part_tris, &v, &f, dist);
        assert!(
            err <= 0.08 + 1e-4,
            "offset by {d}: {at:?} is {err:.4} mm off"
        );
        for p in v
            .iter()
            .filter(|p| (0.0..=12.0).contains(&p[0]) && (0.0..=10.0).contains(&p[1]))
        {
            let above = p[2] - wave(p[0], p[1]);
            assert!(above * dist > 0.0, "offset by {d}: {p:?} on the other side");
        }
    }
}
