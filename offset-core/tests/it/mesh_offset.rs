//! Mesh offsets by multiple normals, checked against the distance they promise: every
//! output face sampled (corners, edges, inside) lies at the offset distance from the input
//! within the tolerance, and the output is closed (every edge shared by exactly two faces,
//! turning opposite ways).

use offset_core::mesh::offset::{measure_error, offset, MeshOffsetOptions, OffsetMethod};
use offset_core::mesh::shapes::{cube_with_boss, cuboid, sphere};
use offset_core::mesh::{Mesh, MeshError, V3};

fn check(case: &str, m: &Mesh, d: f64, tol: f64) -> Mesh {
    let r = offset(m, d, &MeshOffsetOptions { tolerance: tol }).unwrap();
    let rep = r.mesh.report();
    assert!(
        rep.closed,
        "{case}: the offset by {d} is not closed: {} boundary edges, {} non-manifold, {} flipped faces",
        rep.boundary_edges,
        rep.non_manifold_edges,
        rep.flipped_faces.len()
    );
    let (err, n) = measure_error(m, &r.mesh, d, 4);
    assert!(
        err <= tol,
        "{case}: offset by {d}: worst distance error {err:.5} mm over {n} sampled points, tolerance {tol}"
    );
    assert_eq!(r.report.faces_out, r.mesh.faces.len(), "{case}");
    r.mesh
}

#[test]
fn a_cube_with_a_boss_grown_by_2_is_at_the_distance_and_closed() {
    let m = cube_with_boss(30.0, 6.0, 8.0, 64);
    let out = check("cube with boss, 64 steps", &m, 2.0, 0.01);
    // it grew: the top of the boss moved up by d
    let top = out.bounds().unwrap().1.z;
    assert!((top - 40.0).abs() < 1e-9, "boss top at {top}");
}

#[test]
fn a_cube_with_a_coarse_boss_grown_by_2_has_blends_along_the_boss_edges() {
    // 16 steps: 22.5° between the boss's sides, too sharp to share one normal at 0.01
    let m = cube_with_boss(30.0, 6.0, 8.0, 16);
    let r = offset(&m, 2.0, &MeshOffsetOptions { tolerance: 0.01 }).unwrap();
    assert!(
        r.report.split_vertices >= 16 + 8,
        "split vertices {}",
        r.report.split_vertices
    );
    check("cube with boss, 16 steps", &m, 2.0, 0.01);
}

/// One case of the cube with a boss: boss steps, distance, tolerance.
macro_rules! boss_case {
    ($name:ident, $steps:expr, $d:expr, $tol:expr) => {
        #[test]
        fn $name() {
            let m = cube_with_boss(30.0, 6.0, 8.0, $steps);
            check(stringify!($name), &m, $d, $tol);
        }
    };
}

boss_case!(boss_8_steps_grown_by_half, 8, 0.5, 0.01);
boss_case!(boss_24_steps_grown_by_4, 24, 4.0, 0.02);
boss_case!(boss_32_steps_grown_by_2, 32, 2.0, 0.01);
boss_case!(boss_16_steps_shrunk_by_2, 16, -2.0, 0.01);

#[test]
fn a_cube_with_a_boss_shrunk_by_1_is_at_the_distance_and_closed() {
    let m = cube_with_boss(30.0, 6.0, 8.0, 64);
    let out = check("cube with boss shrunk", &m, -1.0, 0.01);
    assert!(out.volume() < m.volume());
}

#[test]
fn a_cube_with_a_boss_at_a_loose_tolerance_stays_within_it() {
    let m = cube_with_boss(30.0, 6.0, 8.0, 32);
    check("cube with boss at 0.1", &m, 3.0, 0.1);
}

#[test]
fn a_sphere_grown_by_1_is_at_the_distance_and_closed() {
    let m = sphere(V3::new(1.0, 2.0, 3.0), 10.0, 24, 48);
    check("sphere r10", &m, 1.0, 0.01);
}

#[test]
fn a_box_grown_and_shrunk_keeps_its_faces_flat() {
    let m = cuboid(V3::ZERO, V3::new(10.0, 8.0, 6.0));
    check("box grown", &m, 1.5, 0.005);
    let s = check("box shrunk", &m, -1.5, 0.005);
    assert!((s.volume() - 7.0 * 5.0 * 3.0).abs() < 1e-9);
}

#[test]
fn an_open_mesh_is_offset_one_sided_and_one_turned_against_itself_is_refused() {
    // a box without its top: grown on the side its faces' normals point to (out)
    let mut m = cuboid(V3::ZERO, V3::new(4.0, 4.0, 4.0));
    let top: Vec<usize> = (0..m.faces.len())
        .filter(|&f| m.face_normal(f).z > 0.9)
        .collect();
    for f in top.into_iter().rev() {
        m.faces.remove(f);
    }
    let r = offset(&m, 1.0, &MeshOffsetOptions { tolerance: 0.05 }).unwrap();
    assert_eq!(r.report.method, OffsetMethod::OneSided);
    // every vertex outside the box's walls and floor (the open top is no wall; the cut
    // along the rim, in the walls' planes, is ragged by up to a grid step)
    let g = r.report.grid_step;
    for v in &r.mesh.vertices {
        let outside = v.x < g || v.x > 4.0 - g || v.y < g || v.y > 4.0 - g || v.z < g;
        assert!(outside, "{v:?} is inside the open box");
    }
    assert!(
        r.mesh.vertices.iter().any(|v| v.x < -0.99) && r.mesh.vertices.iter().any(|v| v.z < -0.99)
    );
    // faces turned against their neighbours leave no side to offset: refused naming them
    m.faces[0].swap(1, 2);
    let e = offset(&m, 1.0, &Default::default()).unwrap_err();
    assert!(matches!(e, MeshError::Flipped { .. }), "{e}");
}

#[test]
fn a_non_manifold_mesh_is_refused_naming_the_edge() {
    let mut m = cuboid(V3::ZERO, V3::new(1.0, 1.0, 1.0));
    // a fin on the box's first edge: that edge now has three faces
    let extra = m.vertices.len() as u32;
    m.vertices.push(V3::new(0.5, -1.0, -1.0));
    let f0 = m.faces[0];
    m.faces.push([f0[0], f0[1], extra]);
    let e = offset(&m, 1.0, &Default::default()).unwrap_err();
    assert!(e.to_string().contains("shared by 3 faces"), "{e}");
}

#[test]
fn a_mesh_with_a_flipped_face_is_refused_naming_it() {
    let mut m = cuboid(V3::ZERO, V3::new(1.0, 1.0, 1.0));
    let [a, b, c] = m.faces[7];
    m.faces[7] = [a, c, b];
    let e = offset(&m, 1.0, &Default::default()).unwrap_err();
    assert!(e.to_string().contains("flipped), faces 7"), "{e}");
}
