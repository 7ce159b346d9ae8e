//! Meshes made from formulas: boxes, surfaces of revolution (spheres, domes, bowls,
//! cylinders), height fields and a cube with a cylinder boss, for tests, benchmarks and
//! demonstrations.

use super::{Mesh, V3};
use std::f64::consts::TAU;

/// A closed box from `lo` to `hi`, normals out.
pub fn cuboid(lo: V3, hi: V3) -> Mesh {
    let v = |i: usize| {
        V3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        )
    };
    let vertices = (0..8).map(v).collect();
    // each side as two triangles, counter-clockwise seen from outside
    let quads = [
        [0, 2, 3, 1], // bottom (z = lo)
        [4, 5, 7, 6], // top
        [0, 1, 5, 4], // y = lo
        [2, 6, 7, 3], // y = hi
        [0, 4, 6, 2], // x = lo
        [1, 3, 7, 5], // x = hi
    ];
    let mut faces = Vec::new();
    for q in quads {
        faces.push([q[0], q[1], q[2]]);
        faces.push([q[0], q[2], q[3]]);
    }
    Mesh::new("box", vertices, faces)
}

/// The surface swept by turning the profile `(r, z)` (r ≥ 0, from one end to the other)
/// about the Z axis through (cx, cy) in `segments` steps. Profile points on the axis
/// (r = 0) become single vertices, so a profile that starts and ends on the axis gives a
/// closed solid. Faces point to the left of the profile's direction of travel seen with
/// the axis on the left: a profile running down the outside (a dome from its pole to its
/// rim) faces out.
pub fn revolve(cx: f64, cy: f64, profile: &[(f64, f64)], segments: usize) -> Mesh {
    let segments = segments.max(3);
    let mut vertices = Vec::new();
    let mut ring: Vec<Vec<u32>> = Vec::new();
    for &(r, z) in profile {
        if r <= 0.0 {
            let i = vertices.len() as u32;
            vertices.push(V3::new(cx, cy, z));
            ring.push(vec![i; segments]);
        } else {
            let mut idx = Vec::with_capacity(segments);
            for k in 0..segments {
                let a = TAU * k as f64 / segments as f64;
                idx.push(vertices.len() as u32);
                vertices.push(V3::new(cx + r * a.cos(), cy + r * a.sin(), z));
            }
            ring.push(idx);
        }
    }
    let mut faces = Vec::new();
    for j in 0..profile.len().saturating_sub(1) {
        for i in 0..segments {
            let i1 = (i + 1) % segments;
            let (a, b) = (ring[j][i], ring[j][i1]);
            let (d, c) = (ring[j + 1][i], ring[j + 1][i1]);
            if a != d && d != c && a != c {
                faces.push([a, d, c]);
            }
            if a != c && c != b && a != b {
                faces.push([a, c, b]);
            }
        }
    }
    Mesh::new("revolved", vertices, faces)
}

/// A sphere of `radius` about `c`, closed, `rings` steps from pole to pole.
pub fn sphere(c: V3, radius: f64, rings: usize, segments: usize) -> Mesh {
    let rings = rings.max(2);
    let profile: Vec<(f64, f64)> = (0..=rings)
        .map(|j| {
            let phi = std::f64::consts::PI * j as f64 / rings as f64;
            (radius * phi.sin(), c.z + radius * phi.cos())
        })
        .map(|(r, z)| (if r.abs() < 1e-12 { 0.0 } else { r }, z))
        .collect();
    let mut m = revolve(c.x, c.y, &profile, segments);
    m.name = "sphere".into();
    m
}

/// A closed upright cylinder: axis through (cx, cy), from `z0` up `height`.
pub fn cylinder(cx: f64, cy: f64, z0: f64, radius: f64, height: f64, segments: usize) -> Mesh {
    let profile = [
        (0.0, z0 + height),
        (radius, z0 + height),
        (radius, z0),
        (0.0, z0),
    ];
    let mut m = revolve(cx, cy, &profile, segments);
    m.name = "cylinder".into();
    m
}

/// An open surface z = f(x, y) over a grid of `nx` × `ny` cells (two triangles each),
/// facing up.
pub fn height_field(
    x: (f64, f64),
    y: (f64, f64),
    nx: usize,
    ny: usize,
    f: impl Fn(f64, f64) -> f64,
) -> Mesh {
    let (nx, ny) = (nx.max(1), ny.max(1));
    let mut vertices = Vec::with_capacity((nx + 1) * (ny + 1));
    for j in 0..=ny {
        let py = y.0 + (y.1 - y.0) * j as f64 / ny as f64;
        for i in 0..=nx {
            let px = x.0 + (x.1 - x.0) * i as f64 / nx as f64;
            vertices.push(V3::new(px, py, f(px, py)));
        }
    }
    let id = |i: usize, j: usize| (j * (nx + 1) + i) as u32;
    let mut faces = Vec::with_capacity(2 * nx * ny);
    for j in 0..ny {
        for i in 0..nx {
            faces.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            faces.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    Mesh::new("height field", vertices, faces)
}

/// A closed solid: the surface z = f(x, y) over the grid, walls down to `base` and a flat
/// bottom there (f must stay above `base`).
pub fn height_field_solid(
    x: (f64, f64),
    y: (f64, f64),
    nx: usize,
    ny: usize,
    base: f64,
    f: impl Fn(f64, f64) -> f64,
) -> Mesh {
    let mut m = height_field(x, y, nx, ny, f);
    let (nx, ny) = (nx.max(1), ny.max(1));
    let id = |i: usize, j: usize| (j * (nx + 1) + i) as u32;
    // the rim, counter-clockwise seen from above
    let mut rim = Vec::new();
    for i in 0..nx {
        rim.push(id(i, 0));
    }
    for j in 0..ny {
        rim.push(id(nx, j));
    }
    for i in (1..=nx).rev() {
        rim.push(id(i, ny));
    }
    for j in (1..=ny).rev() {
        rim.push(id(0, j));
    }
    close_down(&mut m, &rim, base);
    m.name = "height field solid".into();
    m
}

/// Closes an open surface whose rim `rim` runs counter-clockwise seen from above: walls
/// straight down to `base` and a bottom fanned from the rim's centroid (the rim's plan
/// view must be star-shaped about it).
pub fn close_down(m: &mut Mesh, rim: &[u32], base: f64) {
    let n = rim.len();
    let first_low = m.vertices.len() as u32;
    let mut c = V3::ZERO;
    for &v in rim {
        let p = m.vertices[v as usize];
        m.vertices.push(V3::new(p.x, p.y, base));
        c += V3::new(p.x, p.y, base);
    }
    c = c / n as f64;
    let centre = m.vertices.len() as u32;
    m.vertices.push(c);
    for k in 0..n {
        let k1 = (k + 1) % n;
        let (a, b) = (rim[k], rim[k1]);
        let (la, lb) = (first_low + k as u32, first_low + k1 as u32);
        // wall: outward = right of the rim's travel seen from above
        m.faces.push([a, la, lb]);
        m.faces.push([a, lb, b]);
        // bottom, facing down
        m.faces.push([centre, lb, la]);
    }
}

/// A cube of side `size` (from the origin, Z up to `size`) with a cylinder boss of
/// `boss_radius` and `boss_height` standing on the middle of its top; closed, the top
/// face meshed as a ring between the square and the boss's foot. `segments` (a multiple
/// of 8, raised to one) steps round the boss.
pub fn cube_with_boss(size: f64, boss_radius: f64, boss_height: f64, segments: usize) -> Mesh {
    let n = segments.max(8).div_ceil(8) * 8;
    let h = size / 2.0;
    let c = V3::new(h, h, size);
    let mut vertices = Vec::new();
    let mut push = |p: V3| {
        vertices.push(p);
        (vertices.len() - 1) as u32
    };
    // the square rim of the top at the same angles as the boss (the corners are at the
    // diagonals: every n/8-th step)
    let mut sq = Vec::with_capacity(n);
    let mut foot = Vec::with_capacity(n);
    let mut head = Vec::with_capacity(n);
    for k in 0..n {
        let a = TAU * k as f64 / n as f64;
        let (ca, sa) = (a.cos(), a.sin());
        let s = h / ca.abs().max(sa.abs());
        let snap = |v: f64| {
            if (v.abs() - h).abs() < 1e-12 {
                h * v.signum()
            } else {
                v
            }
        };
        sq.push(push(V3::new(c.x + snap(s * ca), c.y + snap(s * sa), size)));
        foot.push(push(V3::new(
            c.x + boss_radius * ca,
            c.y + boss_radius * sa,
            size,
        )));
        head.push(push(V3::new(
            c.x + boss_radius * ca,
            c.y + boss_radius * sa,
            size + boss_height,
        )));
    }
    let top_centre = push(V3::new(c.x, c.y, size + boss_height));
    let bottom: Vec<u32> = [(0.0, 0.0), (size, 0.0), (size, size), (0.0, size)]
        .iter()
        .map(|&(x, y)| push(V3::new(x, y, 0.0)))
        .collect();
    let mut faces = Vec::new();
    for k in 0..n {
        let k1 = (k + 1) % n;
        // top ring between the square and the boss's foot
        faces.push([sq[k], sq[k1], foot[k1]]);
        faces.push([sq[k], foot[k1], foot[k]]);
        // boss side and top
        faces.push([foot[k], foot[k1], head[k1]]);
        faces.push([foot[k], head[k1], head[k]]);
        faces.push([head[k], head[k1], top_centre]);
    }
    // the four sides: the top edge holds the square rim's points between two corners
    // (corners at k = n/8, 3n/8, 5n/8, 7n/8); fan each side from its bottom corner
    let corner_k = |q: usize| (n / 8 + q * n / 4) % n;
    // side q runs from corner q-1 to corner q along the top (counter-clockwise); its
    // bottom corners: below those
    // corner 0 at 45° is (size, size); bottom indices: 0:(0,0) 1:(size,0) 2:(size,size) 3:(0,size)
    let below = [2usize, 3, 0, 1]; // bottom corner under square corner q
    for q in 0..4 {
        let from = corner_k((q + 3) % 4);
        let to = corner_k(q);
        let mut top = vec![sq[from]];
        let mut k = from;
        while k != to {
            k = (k + 1) % n;
            top.push(sq[k]);
        }
        // seen from outside the top runs left to right (counter-clockwise about +Z)
        let b_from = bottom[below[(q + 3) % 4]];
        let b_to = bottom[below[q]];
        faces.push([b_from, b_to, top[0]]);
        for w in top.windows(2) {
            faces.push([b_to, w[1], w[0]]);
        }
    }
    faces.push([bottom[0], bottom[2], bottom[1]]);
    faces.push([bottom[0], bottom[3], bottom[2]]);
    Mesh::new("cube with boss", vertices, faces)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn assert_closed_out(m: &Mesh, volume: f64, tol: f64) {
        let r = m.report();
        assert!(r.closed, "{}: {r:?}", m.name);
        assert!(
            (m.volume() - volume).abs() <= tol,
            "{}: volume {} vs {volume}",
            m.name,
            m.volume()
        );
    }

    #[test]
    fn generated_solids_are_closed_and_face_out() {
        assert_closed_out(&cuboid(V3::ZERO, V3::new(2.0, 3.0, 4.0)), 24.0, 1e-12);
        let s = sphere(V3::new(1.0, 2.0, 3.0), 5.0, 40, 80);
        assert_closed_out(&s, 4.0 / 3.0 * std::f64::consts::PI * 125.0, 5.0);
        let c = cylinder(0.0, 0.0, 0.0, 2.0, 3.0, 64);
        assert_closed_out(&c, std::f64::consts::PI * 12.0, 0.1);
        let hf = height_field_solid((0.0, 4.0), (0.0, 2.0), 8, 4, -1.0, |x, _| 1.0 + x * 0.25);
        // over [0,4]×[0,2]: mean height 1.5 above z = 0, plus the 1 mm below
        assert_closed_out(&hf, 8.0 * 2.5, 1e-9);
        let n = 64;
        let cb = cube_with_boss(20.0, 5.0, 6.0, n);
        let boss = 0.5 * n as f64 * (TAU / n as f64).sin() * 25.0 * 6.0;
        assert_closed_out(&cb, 8000.0 + boss, 1e-6);
    }
}
