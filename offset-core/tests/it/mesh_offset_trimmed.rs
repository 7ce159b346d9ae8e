//! The trimmed mesh offset on parts whose offsets interfere — a U-channel whose slot is
//! narrower than twice the distance, a stepped block whose fillets are smaller than it, two
//! cubes sharing a face and two sharing an edge — grown and shrunk, each checked by the
//! independent checks of testkit/src/mesh_check.rs: closed and manifold, no two faces crossing
//! (triangle–triangle), every vertex and face sample at |d| from the part within the
//! tolerance (exact point–triangle distances), and on the right side of the part; and an
//! open height-field patch offset one-sided, checked the same way (open, on its side).

use crate::common::mesh_check as mc;
use offset_core::mesh::offset::{offset, MeshOffsetOptions, OffsetMethod};
use offset_core::mesh::shapes::{filleted_step, touching_cubes, u_channel};
use offset_core::mesh::Mesh;

fn points(m: &Mesh) -> Vec<mc::P> {
    m.vertices.iter().map(|v| [v.x, v.y, v.z]).collect()
}

fn faces(m: &Mesh) -> Vec<[usize; 3]> {
    m.faces.iter().map(|f| f.map(|i| i as usize)).collect()
}

/// Offsets `part` by `d` at `tol` and checks the result; returns it.
fn check(case: &str, part: &Mesh, d: f64, tol: f64) -> Mesh {
    let r = offset(part, d, &MeshOffsetOptions { tolerance: tol })
        .unwrap_or_else(|e| panic!("{case}: offset by {d}: {e}"));
    let out = &r.mesh;
    assert_eq!(
        r.report.method,
        OffsetMethod::Trimmed,
        "{case}: offsets interfere here, the multiple-normal offset cannot be within {tol}"
    );
    assert!(out.faces.len() > 100, "{case}: {} faces", out.faces.len());
    let (v, f) = (points(out), faces(out));
    if let Err(e) = mc::closed_manifold(&f) {
        panic!("{case}: the offset by {d} is not a closed manifold: {e}");
    }
    let crossing = mc::self_intersections(&v, &f, 5);
    assert!(
        crossing.is_empty(),
        "{case}: the offset by {d} intersects itself: faces {crossing:?}"
    );
    let part_tris: Vec<[mc::P; 3]> = part
        .triangles()
        .map(|t| t.map(|p| [p.x, p.y, p.z]))
        .collect();
    let surface = mc::outer_triangles(&part_tris);
    let (err, at) = mc::worst_distance_error(&surface, &v, &f, d);
    assert!(
        err <= tol,
        "{case}: offset by {d}: a point at {at:?} is {err:.5} mm off the distance (tolerance {tol})"
    );
    // grown: outside the part and more volume; shrunk: inside and less
    let part_volume = part.volume();
    let vol = mc::volume(&v, &f);
    for (i, p) in v.iter().enumerate().step_by(97) {
        assert_eq!(
            mc::inside(&part_tris, *p),
            d < 0.0,
            "{case}: vertex {i} at {p:?} is on the wrong side of the part"
        );
    }
    if d > 0.0 {
        assert!(
            vol > part_volume,
            "{case}: volume {vol} of the grown part, part {part_volume}"
        );
    } else {
        assert!(
            vol > 0.0 && vol < part_volume,
            "{case}: volume {vol} of the shrunk part, part {part_volume}"
        );
    }
    assert!(
        r.report.worst_error <= tol && r.report.faces_out == out.faces.len(),
        "{case}: report {:?}",
        r.report
    );
    r.mesh
}

const TOL: f64 = 0.1;

#[test]
fn a_u_channel_whose_slot_is_narrower_than_2d_grown_fills_the_slot() {
    // slot 2 wide, d = 1.5: the walls' offsets meet over the slot
    let part = u_channel(10.0, 6.0, 2.0, 2.0, 8.0);
    let out = check("u-channel grown by 1.5", &part, 1.5, TOL);
    // nothing of the slot is left: no point of the offset lies in it
    let in_slot = |p: &&offset_core::mesh::V3| {
        p.x > 4.0 && p.x < 6.0 && p.z > 0.0 && p.z < 6.0 && p.y > 0.0 && p.y < 8.0
    };
    assert_eq!(
        out.vertices.iter().find(in_slot),
        None,
        "a vertex in the slot"
    );
}

#[test]
fn a_u_channel_shrunk_by_more_than_half_its_floor_parts_in_two() {
    // the floor is 2 thick: shrunk by 1.5 only the walls' cores are left
    let part = u_channel(10.0, 6.0, 2.0, 2.0, 8.0);
    let out = check("u-channel shrunk by 1.5", &part, -1.5, TOL);
    assert!(out.vertices.iter().all(|p| !(p.x > 4.0 && p.x < 6.0)));
}

#[test]
fn a_step_with_a_concave_fillet_smaller_than_d_grown() {
    let part = filleted_step(12.0, 8.0, 4.0, 0.5, 6, 8.0);
    check("filleted step grown by 1.5", &part, 1.5, TOL);
}

#[test]
fn a_step_with_a_convex_fillet_smaller_than_d_shrunk() {
    let part = filleted_step(12.0, 8.0, 4.0, 0.5, 6, 8.0);
    check("filleted step shrunk by 1.5", &part, -1.5, TOL);
}

#[test]
fn two_cubes_sharing_a_face_grown_and_shrunk_as_one_block() {
    let part = touching_cubes(5.0, false);
    check("cubes sharing a face grown by 1", &part, 1.0, TOL);
    let s = check("cubes sharing a face shrunk by 1", &part, -1.0, TOL);
    // one block 8 × 3 × 3, not two cubes of 3 × 3 × 3
    let vol = mc::volume(&points(&s), &faces(&s));
    assert!((vol - 72.0).abs() < 72.0 * 0.02, "shrunk volume {vol}");
}

#[test]
fn two_cubes_sharing_an_edge_grown_and_shrunk() {
    let part = touching_cubes(5.0, true);
    check("cubes sharing an edge grown by 1", &part, 1.0, TOL);
    let s = check("cubes sharing an edge shrunk by 1", &part, -1.0, TOL);
    let vol = mc::volume(&points(&s), &faces(&s));
    assert!((vol - 54.0).abs() < 54.0 * 0.02, "shrunk volume {vol}");
}

#[test]
fn where_no_offsets_interfere_the_multiple_normal_offset_is_kept() {
    let part = u_channel(10.0, 6.0, 4.0, 2.0, 8.0);
    // slot 4 wide, d = 1: the floor's and walls' offsets meet at the concave edges exactly
    let r = offset(&part, 1.0, &MeshOffsetOptions { tolerance: TOL }).unwrap();
    assert_eq!(
        r.report.method,
        OffsetMethod::MultipleNormals,
        "{:?}",
        r.report
    );
}

/// The checks themselves can fail: two boxes that pass through each other are found
/// crossing, a box with a face missing is open, and a box measured against the wrong
/// distance is off it.
#[test]
fn the_independent_checks_find_crossing_open_and_distant_meshes() {
    use offset_core::mesh::shapes::cuboid;
    use offset_core::mesh::V3;
    let a = cuboid(V3::ZERO, V3::new(2.0, 2.0, 2.0));
    let b = cuboid(V3::new(1.0, 1.0, 1.0), V3::new(3.0, 3.0, 3.0));
    let tris: Vec<_> = a.triangles().chain(b.triangles()).collect();
    let both = Mesh::from_triangles("two boxes", &tris, 1e-9);
    assert!(mc::closed_manifold(&faces(&both)).is_ok());
    assert!(!mc::self_intersections(&points(&both), &faces(&both), 1).is_empty());
    let mut open = a.clone();
    open.faces.pop();
    assert!(mc::closed_manifold(&faces(&open)).is_err());
    let grown = offset(&a, 1.0, &MeshOffsetOptions { tolerance: TOL })
        .unwrap()
        .mesh;
    let part: Vec<[mc::P; 3]> = a.triangles().map(|t| t.map(|p| [p.x, p.y, p.z])).collect();
    let (err, _) = mc::worst_distance_error(&part, &points(&grown), &faces(&grown), 1.2);
    assert!(err > 0.15, "a box grown by 1 measured against 1.2: {err}");
    // an edge blend's chord: a flat face inside the arc is found between the corners
    let (err, _) = mc::worst_distance_error(&part, &points(&grown), &faces(&grown), 1.0);
    assert!(err <= TOL, "{err}");
}

/// An open height-field patch (a wave over 12 × 10 mm, its faces' normals up) offset by
/// ±1 mm: one-sided, every vertex and face sample at 1 mm from the patch within the
/// tolerance, no two faces crossing, open; grown, every vertex over the patch lies above it
/// and, shrunk, below it; the faces turn as the patch's do.
#[test]
fn an_open_height_field_offsets_one_sided_at_the_distance() {
    use offset_core::mesh::shapes::height_field;
    let wave = |x: f64, y: f64| 2.0 + 0.8 * (x / 3.0).sin() * (y / 4.0).cos();
    let patch = height_field((0.0, 12.0), (0.0, 10.0), 24, 20, wave);
    let tris: Vec<[mc::P; 3]> = patch
        .triangles()
        .map(|t| t.map(|p| [p.x, p.y, p.z]))
        .collect();
    let tol = 0.08;
    for d in [1.0, -1.0] {
        let r = offset(&patch, d, &MeshOffsetOptions { tolerance: tol })
            .unwrap_or_else(|e| panic!("offset by {d}: {e}"));
        assert_eq!(r.report.method, OffsetMethod::OneSided, "offset by {d}");
        let out = &r.mesh;
        let (v, f) = (points(out), faces(out));
        assert!(f.len() > 500, "offset by {d}: {} faces", f.len());
        assert!(
            mc::closed_manifold(&f).is_err(),
            "offset by {d}: one side of an open patch is open"
        );
        let crossing = mc::self_intersections(&v, &f, 5);
        assert!(
            crossing.is_empty(),
            "offset by {d}: faces {crossing:?} cross"
        );
        let (err, at) = mc::worst_distance_error(&tris, &v, &f, d);
        assert!(err <= tol, "offset by {d}: {at:?} is {err:.4} mm off");
        // over the patch, on the asked side only
        let over: Vec<&mc::P> = v
            .iter()
            .filter(|p| (0.0..=12.0).contains(&p[0]) && (0.0..=10.0).contains(&p[1]))
            .collect();
        assert!(
            over.len() > 200,
            "offset by {d}: {} vertices over the patch",
            over.len()
        );
        for p in over {
            let above = p[2] - wave(p[0], p[1]);
            assert!(above * d > 0.0, "offset by {d}: {p:?} is on the other side");
        }
        // the faces turn as the patch's (up)
        let up = (0..out.faces.len())
            .filter(|&k| out.face_normal(k).z > 0.0)
            .count();
        assert!(
            up * 10 > out.faces.len() * 9,
            "offset by {d}: {up} of {} faces turn up",
            out.faces.len()
        );
    }
}
