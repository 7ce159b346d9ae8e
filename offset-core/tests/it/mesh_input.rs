//! Reading meshes: binary and ASCII STL agree, vertices weld, and bad input (cut-short
//! files, NaN vertices, meshes with no area, non-manifold meshes, too many faces) is one
//! sentence naming the file and the face, never a panic.

use offset_core::mesh::shapes::cuboid;
use offset_core::mesh::stl::write_ascii_stl;
use offset_core::mesh::{offset, read_stl, rough3d, write_stl, MeshError, MeshOptions, V3};
use proptest::prelude::*;

fn opts() -> MeshOptions {
    MeshOptions::default()
}

#[test]
fn binary_and_ascii_stl_read_to_the_same_welded_box() {
    let m = cuboid(V3::new(1.0, 2.0, 3.0), V3::new(4.0, 6.0, 8.0));
    let bin = read_stl(&write_stl(&m), "box.stl", &opts()).unwrap();
    let asc = read_stl(write_ascii_stl(&m).as_bytes(), "box.stl", &opts()).unwrap();
    for r in [&bin, &asc] {
        assert_eq!((r.vertices.len(), r.faces.len()), (8, 12));
        assert!(r.report().closed);
        assert!((r.volume() - 60.0).abs() < 1e-9, "{}", r.volume());
    }
}

#[test]
fn a_binary_stl_whose_header_starts_with_solid_is_read_as_binary() {
    let m = cuboid(V3::ZERO, V3::new(1.0, 1.0, 1.0));
    let mut b = write_stl(&m);
    b[..11].copy_from_slice(b"solid cube ");
    let r = read_stl(&b, "cube.stl", &opts()).unwrap();
    assert_eq!(r.faces.len(), 12);
}

#[test]
fn a_cut_short_binary_stl_says_how_many_faces_it_holds() {
    let m = cuboid(V3::ZERO, V3::new(1.0, 1.0, 1.0));
    let b = write_stl(&m);
    let e = read_stl(&b[..84 + 50 * 7 + 20], "part.stl", &opts()).unwrap_err();
    assert_eq!(
        e.to_string(),
        "part.stl is cut short: its header promises 12 faces but the file holds 7"
    );
}

#[test]
fn a_cut_short_ascii_stl_names_the_face() {
    let m = cuboid(V3::ZERO, V3::new(1.0, 1.0, 1.0));
    let t = write_ascii_stl(&m);
    let cut = &t[..t.len() / 2];
    let e = read_stl(cut.as_bytes(), "part.stl", &opts())
        .unwrap_err()
        .to_string();
    assert!(
        e.starts_with("part.stl: the ASCII STL is cut short in face "),
        "{e}"
    );
}

#[test]
fn a_tiny_file_is_not_an_stl() {
    let e = read_stl(b"hello", "part.stl", &opts())
        .unwrap_err()
        .to_string();
    assert!(e.contains("too short for an STL file"), "{e}");
}

#[test]
fn a_nan_vertex_names_the_face_and_corner() {
    let m = cuboid(V3::ZERO, V3::new(1.0, 1.0, 1.0));
    let mut b = write_stl(&m);
    // face 5, corner 2, its y: 84 + 50·5 + 12 (normal) + 12·2 + 4
    let at = 84 + 50 * 5 + 12 + 24 + 4;
    b[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    let e = read_stl(&b, "part.stl", &opts()).unwrap_err();
    assert_eq!(
        e.to_string(),
        "part.stl: vertex 2 of face 5 is not a finite number"
    );
}

#[test]
fn a_nan_vertex_in_ascii_names_the_face() {
    let t = "solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 nan\nvertex 0 1 0\nendloop\nendfacet\nendsolid x\n";
    let e = read_stl(t.as_bytes(), "part.stl", &opts())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("face 0") && e.contains("not a finite number"),
        "{e}"
    );
}

#[test]
fn a_mesh_of_degenerate_faces_has_no_area() {
    let m = offset_core::mesh::Mesh::new(
        "flat",
        vec![V3::ZERO, V3::new(1.0, 0.0, 0.0), V3::new(2.0, 0.0, 0.0)],
        vec![[0, 1, 2], [2, 1, 0]],
    );
    let e = read_stl(&write_stl(&m), "flat.stl", &opts()).unwrap_err();
    assert!(matches!(e, MeshError::NoArea { .. }), "{e}");
    assert_eq!(
        e.to_string(),
        "flat.stl has no area: all of its 2 faces are degenerate (zero area)"
    );
}

#[test]
fn too_many_faces_are_refused_by_the_budget_before_reading() {
    let m = cuboid(V3::ZERO, V3::new(1.0, 1.0, 1.0));
    let small = MeshOptions {
        max_faces: 10,
        ..opts()
    };
    let e = read_stl(&write_stl(&m), "big.stl", &small)
        .unwrap_err()
        .to_string();
    assert_eq!(
        e,
        "big.stl has 12 faces, more than the budget of 10 (MeshOptions::max_faces)"
    );
    let e = read_stl(write_ascii_stl(&m).as_bytes(), "big.stl", &small)
        .unwrap_err()
        .to_string();
    assert!(e.contains("more than the budget of 10"), "{e}");
}

#[test]
fn a_non_manifold_mesh_is_refused_by_the_offset_and_roughed_with_a_warning() {
    let mut m = cuboid(V3::ZERO, V3::new(1.0, 1.0, 1.0));
    let extra = m.vertices.len() as u32;
    m.vertices.push(V3::new(0.5, -1.0, -1.0));
    let f0 = m.faces[0];
    m.faces.push([f0[0], f0[1], extra]);
    let m = read_stl(&write_stl(&m), "fin.stl", &opts()).unwrap();
    let e1 = offset(&m, 1.0, &Default::default())
        .unwrap_err()
        .to_string();
    assert!(
        e1.starts_with("fin.stl: the edge from vertex") && e1.contains("is shared by 3 faces"),
        "{e1}"
    );
    // the rough needs no solid: it works from the upper envelope and says why
    let p = offset_core::mesh::Rough3dParams {
        stock_margin: 5.0,
        ..Default::default()
    };
    let tp = rough3d(&m, &p).unwrap();
    assert!(
        tp.warnings
            .iter()
            .any(|w| w.contains("fin.stl is open: 2 boundary edges; 1 non-manifold edges")),
        "{:?}",
        tp.warnings
    );
}

#[test]
fn vertices_within_the_weld_tolerance_become_one() {
    let m = cuboid(V3::ZERO, V3::new(1.0, 1.0, 1.0));
    let mut tris: Vec<[V3; 3]> = m.triangles().collect();
    // nudge every corner of one face by less than the tolerance
    for p in &mut tris[3] {
        *p += V3::new(3e-5, -2e-5, 1e-5);
    }
    let n = offset_core::mesh::Mesh::from_triangles("nudged", &tris, 1e-4);
    assert_eq!(n.vertices.len(), 8);
    assert!(n.report().closed);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(offset_core::check::proptest_cases(256)))]

    /// Whatever the bytes, reading gives a mesh or an error, never a panic.
    #[test]
    fn arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..600), solid in any::<bool>()) {
        let mut b = bytes;
        if solid {
            let mut t = b"solid x\n".to_vec();
            t.extend(b);
            b = t;
        }
        let _ = read_stl(&b, "noise.stl", &opts());
        let _ = offset_core::mesh::read_point_grid(&b, "noise.csv");
    }
}
