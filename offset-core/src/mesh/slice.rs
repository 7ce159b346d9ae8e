//! Slicing: a closed mesh cut by a horizontal plane into closed contours (polylines in
//! plan view), robust to vertices, edges and faces lying on the plane.
//!
//! A vertex exactly on the plane counts as below it, so the contours are those of the
//! section just above the plane (what a tool whose tip is at that height would meet), and
//! every crossing is decided by one comparison per vertex: each edge with one end above and
//! one below is crossed once, each face with a crossing has exactly two such edges, and a
//! crossing is named by its edge, so the pieces join into loops without comparing
//! coordinates. Loops run counter-clockwise round material (seen from above) and
//! clockwise round holes.

use super::FastMap;
use super::{Mesh, MeshError};
use crate::geom::{Point, Polyline};

/// The contours of the closed mesh's section just above the plane Z = `z`: loops
/// counter-clockwise round material and clockwise round holes, repeated points dropped.
/// An open mesh leaves a contour unclosed: that is an error naming a face along it.
pub fn slice_at(m: &Mesh, z: f64) -> Result<Vec<Polyline>, MeshError> {
    let above = |v: u32| m.vertices[v as usize].z > z;
    let key = |a: u32, b: u32| (a.min(b), a.max(b));
    let cross = |a: u32, b: u32| {
        let (pa, pb) = (m.vertices[a as usize], m.vertices[b as usize]);
        // from the end below (z_lo ≤ z) to the end above
        let (lo, hi) = if pa.z > z { (pb, pa) } else { (pa, pb) };
        let t = (z - lo.z) / (hi.z - lo.z);
        Point::new(lo.x + (hi.x - lo.x) * t, lo.y + (hi.y - lo.y) * t)
    };
    // each crossed face gives one piece: from its edge going down to its edge going up
    let mut next: FastMap<(u32, u32), ((u32, u32), usize)> = FastMap::default();
    let mut points: FastMap<(u32, u32), Point> = FastMap::default();
    for (f, face) in m.faces.iter().enumerate() {
        let up: [bool; 3] = [above(face[0]), above(face[1]), above(face[2])];
        if up[0] == up[1] && up[1] == up[2] {
            continue;
        }
        let mut down_edge = None;
        let mut up_edge = None;
        for k in 0..3 {
            let (a, b) = (face[k], face[(k + 1) % 3]);
            match (up[k], up[(k + 1) % 3]) {
                (true, false) => down_edge = Some(key(a, b)),
                (false, true) => up_edge = Some(key(a, b)),
                _ => continue,
            }
            points.entry(key(a, b)).or_insert_with(|| cross(a, b));
        }
        let (Some(from), Some(to)) = (down_edge, up_edge) else {
            continue;
        };
        if next.insert(from, (to, f)).is_some() {
            return Err(not_closed(m, f, z));
        }
    }
    let mut loops = Vec::new();
    let mut done: FastMap<(u32, u32), bool> = FastMap::default();
    let mut starts: Vec<(u32, u32)> = next.keys().copied().collect();
    starts.sort_unstable();
    for s in starts {
        if done.contains_key(&s) {
            continue;
        }
        let mut pts: Vec<Point> = Vec::new();
        let mut e = s;
        loop {
            done.insert(e, true);
            let p = points[&e];
            if pts.last().is_none_or(|q: &Point| q.dist(p) > 1e-12) {
                pts.push(p);
            }
            let Some(&(n, f)) = next.get(&e) else {
                unreachable!("every start has a next")
            };
            if n == s {
                break;
            }
            if done.contains_key(&n) || !next.contains_key(&n) {
                return Err(not_closed(m, f, z));
            }
            e = n;
        }
        while pts.len() > 1 && pts[0].dist(pts[pts.len() - 1]) <= 1e-12 {
            pts.pop();
        }
        if pts.len() >= 3 {
            loops.push(Polyline::from_points(&pts, true));
        }
    }
    Ok(loops)
}

fn not_closed(m: &Mesh, face: usize, z: f64) -> MeshError {
    MeshError::Open {
        name: format!("{} (slice at Z {z})", m.name),
        edges: 1,
        faces: vec![face],
    }
}

/// The heights of the mesh's faces that lie flat and face up (within 1e-9 of level),
/// highest first, each once: where a roughing level belongs to leave no step of material
/// on a flat.
pub fn flat_heights(m: &Mesh) -> Vec<f64> {
    let mut zs: Vec<f64> = (0..m.faces.len())
        .filter_map(|f| {
            let n = m.face_area2(f);
            let [a, b, c] = m.triangle(f);
            let level = (a.z - b.z).abs() < 1e-9 && (b.z - c.z).abs() < 1e-9;
            (level && n.z > 0.0).then_some(a.z)
        })
        .collect();
    zs.sort_by(|a, b| b.total_cmp(a));
    zs.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
    zs
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::shapes::{cube_with_boss, cuboid, sphere};
    use crate::mesh::V3;

    #[test]
    fn a_box_sliced_through_its_middle_is_one_square_counter_clockwise() {
        let m = cuboid(V3::ZERO, V3::new(4.0, 3.0, 2.0));
        let loops = slice_at(&m, 1.0).unwrap();
        assert_eq!(loops.len(), 1);
        assert!(
            (loops[0].area() - 12.0).abs() < 1e-12,
            "{}",
            loops[0].area()
        );
    }

    #[test]
    fn a_slice_on_the_top_face_is_empty_and_on_the_bottom_face_is_the_footprint() {
        let m = cuboid(V3::ZERO, V3::new(4.0, 3.0, 2.0));
        assert!(slice_at(&m, 2.0).unwrap().is_empty());
        let loops = slice_at(&m, 0.0).unwrap();
        assert_eq!(loops.len(), 1);
        assert!((loops[0].area() - 12.0).abs() < 1e-12);
    }

    #[test]
    fn a_slice_through_the_boss_is_its_circle_and_on_the_cube_top_too() {
        let n = 64;
        let m = cube_with_boss(20.0, 5.0, 6.0, n);
        let circle = 0.5 * n as f64 * (std::f64::consts::TAU / n as f64).sin() * 25.0;
        for z in [20.0, 23.0] {
            let loops = slice_at(&m, z).unwrap();
            assert_eq!(loops.len(), 1, "at {z}");
            assert!(
                (loops[0].area() - circle).abs() < 1e-9,
                "at {z}: {}",
                loops[0].area()
            );
        }
        let loops = slice_at(&m, 19.999).unwrap();
        assert_eq!(loops.len(), 1);
        assert!((loops[0].area() - 400.0).abs() < 1e-9);
    }

    #[test]
    fn a_sphere_sliced_through_a_ring_of_vertices_is_one_loop() {
        // z = 0 holds the equator's vertices exactly
        let m = sphere(V3::ZERO, 10.0, 20, 40);
        let loops = slice_at(&m, 0.0).unwrap();
        assert_eq!(loops.len(), 1);
        assert!(loops[0].area() > 0.0 && loops[0].len() >= 40);
    }

    #[test]
    fn an_open_mesh_is_named_by_a_face() {
        let mut m = cuboid(V3::ZERO, V3::new(4.0, 3.0, 2.0));
        m.faces.remove(5);
        let e = slice_at(&m, 1.0).unwrap_err();
        assert!(e.to_string().contains("not closed"), "{e}");
    }
}
