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

/// A prism: the simple polygon `profile` (x, z), either turn, swept along Y from 0 to
/// `length`; closed, normals out, its ends triangulated by ear clipping.
pub fn prism_y(profile: &[(f64, f64)], length: f64) -> Mesh {
    let n = profile.len();
    let area: f64 = (0..n)
        .map(|i| {
            let (a, b) = (profile[i], profile[(i + 1) % n]);
            a.0 * b.1 - b.0 * a.1
        })
        .sum();
    // counter-clockwise in (x, z)
    let p: Vec<(f64, f64)> = if area > 0.0 {
        profile.to_vec()
    } else {
        profile.iter().rev().copied().collect()
    };
    let mut vertices = Vec::with_capacity(2 * n);
    for y in [0.0, length] {
        for &(x, z) in &p {
            vertices.push(V3::new(x, y, z));
        }
    }
    let n32 = n as u32;
    let mut faces = Vec::new();
    // (x, z) counter-clockwise seen from -Y: the y = 0 end faces -Y as listed
    for [a, b, c] in ear_clip(&p) {
        faces.push([a, c, b]);
        faces.push([a + n32, b + n32, c + n32]);
    }
    for i in 0..n32 {
        let j = (i + 1) % n32;
        faces.push([i, j, j + n32]);
        faces.push([i, j + n32, i + n32]);
    }
    let mut m = Mesh::new("prism", vertices, faces);
    if m.volume() < 0.0 {
        m = m.flipped();
    }
    m
}

/// The triangles of a simple counter-clockwise polygon, by ear clipping.
fn ear_clip(p: &[(f64, f64)]) -> Vec<[u32; 3]> {
    let cross = |o: (f64, f64), a: (f64, f64), b: (f64, f64)| {
        (a.0 - o.0) * (b.1 - o.1) - (a.1 - o.1) * (b.0 - o.0)
    };
    let mut idx: Vec<usize> = (0..p.len()).collect();
    let mut out = Vec::new();
    while idx.len() > 3 {
        let m = idx.len();
        let ear = (0..m).find(|&k| {
            let (a, b, c) = (idx[(k + m - 1) % m], idx[k], idx[(k + 1) % m]);
            if cross(p[a], p[b], p[c]) <= 0.0 {
                return false;
            }
            idx.iter().all(|&q| {
                q == a
                    || q == b
                    || q == c
                    || !(cross(p[a], p[b], p[q]) >= 0.0
                        && cross(p[b], p[c], p[q]) >= 0.0
                        && cross(p[c], p[a], p[q]) >= 0.0)
            })
        });
        let Some(k) = ear else { break };
        let (a, b, c) = (idx[(k + m - 1) % m], idx[k], idx[(k + 1) % m]);
        out.push([a as u32, b as u32, c as u32]);
        idx.remove(k);
    }
    if idx.len() == 3 {
        out.push([idx[0] as u32, idx[1] as u32, idx[2] as u32]);
    }
    out
}

/// A U-channel `length` long (along Y): `width` wide, `height` high, a slot `slot` wide
/// down to `floor` above the bottom, in the middle.
pub fn u_channel(width: f64, height: f64, slot: f64, floor: f64, length: f64) -> Mesh {
    let (a, b) = ((width - slot) / 2.0, (width + slot) / 2.0);
    let profile = [
        (0.0, 0.0),
        (width, 0.0),
        (width, height),
        (b, height),
        (b, floor),
        (a, floor),
        (a, height),
        (0.0, height),
    ];
    let mut m = prism_y(&profile, length);
    m.name = "u-channel".into();
    m
}

/// A stepped block `length` long (along Y): `width` wide and `height` high on its left
/// half, `step` high on its right; the inner corner of the step rounded by a concave fillet
/// and the top's outer edge by a convex one, both of `radius`, each in `segments` steps.
pub fn filleted_step(
    width: f64,
    height: f64,
    step: f64,
    radius: f64,
    segments: usize,
    length: f64,
) -> Mesh {
    let half = width / 2.0;
    let segments = segments.max(1);
    let quarter = std::f64::consts::FRAC_PI_2;
    let mut p = vec![(0.0, 0.0), (width, 0.0), (width, step)];
    // concave fillet about (half + r, step + r): from (half + r, step) to (half, step + r)
    for k in 0..=segments {
        let a = -quarter - quarter * k as f64 / segments as f64;
        p.push((
            half + radius + radius * a.cos(),
            step + radius + radius * a.sin(),
        ));
    }
    // convex fillet about (half − r, height − r): from (half, height − r) to (half − r, height)
    for k in 0..=segments {
        let a = quarter * k as f64 / segments as f64;
        p.push((
            half - radius + radius * a.cos(),
            height - radius + radius * a.sin(),
        ));
    }
    p.push((0.0, height));
    let mut m = prism_y(&p, length);
    m.name = "filleted step".into();
    m
}

/// Two cubes of side `size`: the second beside the first along X, sharing a whole face
/// (`edge_only` false) or only an edge (`edge_only` true: moved by `size` along Y too);
/// one mesh, vertices welded, so the shared edges have four faces.
pub fn touching_cubes(size: f64, edge_only: bool) -> Mesh {
    let a = cuboid(V3::ZERO, V3::new(size, size, size));
    let o = V3::new(size, if edge_only { size } else { 0.0 }, 0.0);
    let b = cuboid(o, o + V3::new(size, size, size));
    let tris: Vec<[V3; 3]> = a.triangles().chain(b.triangles()).collect();
    Mesh::from_triangles("touching cubes", &tris, 1e-9)
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
