//! 3D work on meshes that are no closed solid, as other programs write them: every solid
//! of a multi-solid ASCII STL is read, the stored normal decides nothing, and rough3d,
//! finish3d and waterline (ball, flat, bull) plan touching bodies, overlapping shells,
//! open surfaces and turned faces, each defect said in one warning line. Roughing keeps
//! the allowance (judged by an independent drop-cutter of the tool grown by it), waterlines
//! touch the part and never gouge it (judged by the drop-cutter of their own cutter), and a
//! rough that would cut nothing is refused in a sentence.

use offset_core::mesh::shapes::{cuboid, height_field, sphere};
use offset_core::mesh::stl::write_ascii_stl;
use offset_core::mesh::{
    read_stl, rough3d, waterline3d, Cutter, DropCutter, Mesh, Rough3dParams, WaterlineParams, V3,
};
use offset_core::ops::Stepover;
use offset_core::toolpath::{Move, Tool, Toolpath, P3};

/// Checks that the flat tool of `p` keeps `p.stock_allowance` from `m` at every sampled
/// position of `tp` (the tool grown by a ball of radius a is a bull cutter of radius r + a
/// and corner a, its tip a below the tool's).
fn keeps_allowance(case: &str, m: &Mesh, p: &Rough3dParams, tp: &Toolpath) {
    let (a, r) = (p.stock_allowance - 1e-6, p.tool.radius());
    let dc = DropCutter::new(m, Cutter::bull(2.0 * (r + a), a)).unwrap();
    let mut n = 0;
    for q in tp.sample(P3::new(0.0, 0.0, 100.0), 0.5) {
        let need = dc.drop(q.x, q.y, -1e9) + a;
        assert!(
            q.z >= need - 1e-9,
            "{case}: the tool at ({:.3}, {:.3}, {:.4}) is {:.4} mm closer to the part than the allowance {}",
            q.x,
            q.y,
            q.z,
            need - q.z,
            p.stock_allowance
        );
        n += 1;
    }
    let cuts = tp
        .moves
        .iter()
        .filter(|mv| matches!(mv, Move::Linear { .. } | Move::Arc { .. }))
        .count();
    assert!(cuts > 10, "{case}: only {cuts} cutting moves");
    eprintln!("{case}: {n} positions keep the allowance, {cuts} cutting moves");
}

fn params(a: f64) -> Rough3dParams {
    Rough3dParams {
        tool: Tool::flat(6.0),
        stepdown: 3.0,
        stepover: Stepover::Percent(45.0),
        stock_allowance: a,
        stock_margin: 4.0,
        tolerance: 0.05,
        ..Default::default()
    }
}

fn soup(name: &str, parts: &[Mesh]) -> Mesh {
    let tris: Vec<[V3; 3]> = parts.iter().flat_map(|m| m.triangles()).collect();
    Mesh::from_triangles(name, &tris, 1e-6)
}

#[test]
fn every_solid_of_a_multi_solid_ascii_stl_is_read() {
    let a = cuboid(V3::ZERO, V3::new(10.0, 10.0, 5.0));
    let b = cuboid(V3::new(20.0, 0.0, 0.0), V3::new(30.0, 10.0, 8.0));
    let c = sphere(V3::new(50.0, 5.0, 5.0), 5.0, 8, 16);
    let mut text = String::new();
    for (k, m) in [&a, &b, &c].iter().enumerate() {
        text.push_str(
            &write_ascii_stl(m)
                .replace("solid machlink", &format!("solid body{k}"))
                .replace("endsolid machlink", &format!("endsolid body{k}")),
        );
    }
    let m = read_stl(text.as_bytes(), "scene.stl", &Default::default()).unwrap();
    assert_eq!(m.faces.len(), a.faces.len() + b.faces.len() + c.faces.len());
    let (lo, hi) = m.bounds().unwrap();
    assert!(
        lo.x.abs() < 1e-6 && (hi.x - 55.0).abs() < 1e-6,
        "{lo:?} {hi:?}"
    );
}

#[test]
fn a_malformed_stored_normal_is_ignored() {
    // OpenSCAD in a locale with decimal commas wrote its normals so (PyCAM's Sphere_cut.stl)
    let t = "solid OpenSCAD_Model\n  facet normal -0,774597 0 0,632456\n    outer loop\n      vertex 0 0 0\n      vertex 1 0 0\n      vertex 0 1 1\n    endloop\n  endfacet\n  facet normal\n    outer loop\n      vertex 1 0 0\n      vertex 1 1 1\n      vertex 0 1 1\n    endloop\n  endfacet\nendsolid OpenSCAD_Model\n";
    let m = read_stl(t.as_bytes(), "cut.stl", &Default::default()).unwrap();
    assert_eq!(m.faces.len(), 2);
    // a bad vertex is still refused, naming the line and the face
    let bad = t.replacen("vertex 1 0 0", "vertex 1,5 0 0", 1);
    let e = read_stl(bad.as_bytes(), "cut.stl", &Default::default())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("line 5") && e.contains("face 0") && e.contains("\"1,5\""),
        "{e}"
    );
}

#[test]
fn two_touching_cubes_are_roughed_keeping_the_allowance_from_both() {
    // they share a face: welded, its rim edges are used by four faces
    let m = soup(
        "touching.stl",
        &[
            cuboid(V3::ZERO, V3::new(10.0, 10.0, 10.0)),
            cuboid(V3::new(10.0, 0.0, 0.0), V3::new(20.0, 10.0, 6.0)),
        ],
    );
    let p = params(0.5);
    let tp = rough3d(&m, &p).unwrap();
    assert!(
        tp.warnings
            .iter()
            .any(|w| w.contains("non-manifold edges") && w.contains("upper envelope")),
        "{:?}",
        tp.warnings
    );
    keeps_allowance("two touching cubes", &m, &p, &tp);
}

#[test]
fn overlapping_shells_and_turned_faces_are_roughed_keeping_the_allowance() {
    let mut m = soup(
        "overlap.stl",
        &[
            cuboid(V3::ZERO, V3::new(12.0, 12.0, 10.0)),
            cuboid(V3::new(6.0, 6.0, 0.0), V3::new(18.0, 18.0, 7.0)),
            sphere(V3::new(6.0, 15.0, 4.0), 4.0, 10, 20),
        ],
    );
    // turn a few faces over, as a careless exporter does
    for f in [0, 3, 7] {
        m.faces[f].swap(1, 2);
    }
    let p = params(0.4);
    let tp = rough3d(&m, &p).unwrap();
    assert!(
        tp.warnings.iter().any(|w| w.contains("turned")),
        "{:?}",
        tp.warnings
    );
    keeps_allowance("overlapping shells", &m, &p, &tp);
}

#[test]
fn an_open_surface_is_roughed_down_to_its_lowest_point() {
    // a wavy sheet, no sides or bottom: everything under it is material
    let m = height_field((0.0, 30.0), (0.0, 20.0), 30, 20, |x, y| {
        3.0 + 2.0 * (x / 5.0).sin() * (y / 4.0).cos()
    });
    let p = params(0.3);
    let tp = rough3d(&m, &p).unwrap();
    assert!(
        tp.warnings.iter().any(|w| w.contains("is open:")),
        "{:?}",
        tp.warnings
    );
    keeps_allowance("open wavy sheet", &m, &p, &tp);
}

#[test]
fn a_rough_whose_stock_is_the_part_is_refused_in_one_sentence() {
    let m = cuboid(V3::ZERO, V3::new(20.0, 10.0, 5.0));
    let p = Rough3dParams {
        stock_margin: 0.0,
        ..params(0.3)
    };
    let e = rough3d(&m, &p).unwrap_err().to_string();
    assert!(
        e.contains("nothing to rough: the stock is the part's own") && e.contains("--stock-margin"),
        "{e}"
    );
    // with room round it, the same part is roughed
    keeps_allowance(
        "box with a margin",
        &m,
        &params(0.3),
        &rough3d(&m, &params(0.3)).unwrap(),
    );
}

#[test]
fn a_rough_with_stock_beside_the_part_that_its_tool_cannot_reach_is_refused_not_sent_empty() {
    // 2 mm of stock round the part and a 20 mm cutter: material is there, but the tool
    // keeping its allowance from the part never fits inside the stock
    let m = cuboid(V3::ZERO, V3::new(20.0, 10.0, 5.0));
    let p = Rough3dParams {
        tool: Tool::flat(20.0),
        stock_margin: 2.0,
        ..params(0.3)
    };
    let e = rough3d(&m, &p).unwrap_err().to_string();
    assert!(
        e.contains("the rough would cut nothing, though the stock holds material")
            && e.contains("refused rather than sent empty"),
        "{e}"
    );
}

/// Every point the waterline passes through leaves the cutter in the part by no more
/// than the tolerance (measured square to it: the least of lifting it and moving it out), and every contour vertex touches the part within the tolerance.
fn waterline_touches_and_never_gouges(case: &str, m: &Mesh, c: Cutter) {
    let tol = 0.01;
    let p = WaterlineParams {
        cutter: c,
        stepdown: 2.0,
        tolerance: tol,
        ..Default::default()
    };
    let tp = waterline3d(m, &p).unwrap();
    let dc = DropCutter::new(m, c).unwrap();
    let low = m.bounds().unwrap().0.z - 1.0;
    let mut worst_gouge = 0.0f64;
    let mut worst_at = P3::default();
    let mut worst_seg = (P3::default(), P3::default());
    let mut worst_gap = 0.0f64;
    let mut vertices = 0;
    tp.walk(P3::new(0.0, 0.0, 100.0), |from, mv, to| {
        let Move::Linear { .. } = mv else { return };
        if (from.z - to.z).abs() > 1e-9 {
            return; // the plunge into a contour
        }
        let (dx, dy) = (to.x - from.x, to.y - from.y);
        let len = dx.hypot(dy).max(1e-12);
        // climb runs clockwise round material: the free side is on the left
        let (nx, ny) = (-dy / len, dx / len);
        for k in 0..=8 {
            let t = k as f64 / 8.0;
            let (x, y) = (from.x + dx * t, from.y + dy * t);
            // how deep the cutter is in, square to the part: the least of lifting it
            // and moving it out sideways (a ball's equator on a wall has a drop-cutter
            // height far above its tip a hair inside the wall)
            let up = dc.drop(x, y, low) - to.z;
            let mut side = 0.0;
            if up > 0.0 {
                side = f64::INFINITY;
                for i in 1..=400 {
                    let s = i as f64 * 0.0025;
                    if dc.drop(x + nx * s, y + ny * s, low) <= to.z {
                        side = s;
                        break;
                    }
                }
            }
            let g = up.min(side);
            if g > worst_gouge {
                worst_gouge = g;
                worst_at = P3::new(x, y, to.z);
                worst_seg = (from, to);
            }
        }
        // the cutter, pushed sideways by the tolerance, meets the part
        vertices += 1;
        let z = dc.drop(to.x, to.y, low);
        if z > low {
            worst_gap = worst_gap.max(to.z - z);
        }
    });
    eprintln!("{case}: {vertices} contour vertices, worst gouge {worst_gouge:.5} mm (square to the part), worst height gap {worst_gap:.5} mm");
    assert!(vertices > 50, "{case}: only {vertices} contour vertices");
    assert!(
        worst_gouge <= tol,
        "{case}: the cutter gouges {worst_gouge:.5} mm between contour points at {worst_at:?} on {worst_seg:?} (tolerance {tol})"
    );
}

#[test]
fn waterlines_with_flat_and_bull_cutters_follow_the_drop_cutter_model() {
    let box_and_ball = soup(
        "block and ball.stl",
        &[
            cuboid(V3::ZERO, V3::new(20.0, 14.0, 6.0)),
            sphere(V3::new(10.0, 7.0, 6.0), 5.0, 12, 24),
        ],
    );
    for (name, c) in [
        ("flat d6", Cutter::flat(6.0)),
        ("bull d6 r1", Cutter::bull(6.0, 1.0)),
        ("ball d4", Cutter::ball(4.0)),
    ] {
        waterline_touches_and_never_gouges(&format!("block and ball, {name}"), &box_and_ball, c);
    }
}
