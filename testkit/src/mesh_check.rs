//! Independent checks of a triangle mesh that claims to be a solid offset of a part: closed
//! and manifold (every edge shared by exactly two faces running it opposite ways, every
//! vertex's faces one fan), free of self-intersection (a triangle–triangle test of its own:
//! edges against triangles, with the shared-vertex and coplanar cases), and at a distance
//! from the part (exact point–triangle distances: the point projected onto the plane, else
//! the nearest of the three edges), sampled at vertices, edge midpoints and inner points.
//! Plain `[f64; 3]` points and the standard library only: nothing of offset-core's geometry
//! is used, so a mistake there cannot hide here.

use std::collections::HashMap;

pub type P = [f64; 3];

fn sub(a: P, b: P) -> P {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn add(a: P, b: P) -> P {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
fn mul(a: P, k: f64) -> P {
    [a[0] * k, a[1] * k, a[2] * k]
}
fn dot(a: P, b: P) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross(a: P, b: P) -> P {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
fn norm(a: P) -> f64 {
    dot(a, a).sqrt()
}

/// Every edge used by exactly two faces, once each way, and every vertex's faces one fan.
pub fn closed_manifold(faces: &[[usize; 3]]) -> Result<(), String> {
    let mut directed: HashMap<(usize, usize), usize> = HashMap::new();
    for (i, f) in faces.iter().enumerate() {
        if f[0] == f[1] || f[1] == f[2] || f[0] == f[2] {
            return Err(format!("face {i} repeats a vertex: {f:?}"));
        }
        for k in 0..3 {
            if let Some(j) = directed.insert((f[k], f[(k + 1) % 3]), i) {
                return Err(format!(
                    "faces {j} and {i} both run the edge {} → {} the same way (not manifold or not oriented)",
                    f[k],
                    f[(k + 1) % 3]
                ));
            }
        }
    }
    for (&(a, b), &i) in &directed {
        if !directed.contains_key(&(b, a)) {
            return Err(format!(
                "the edge {a} → {b} of face {i} has no face running it back (open)"
            ));
        }
    }
    // around each vertex, the faces' far edges (a → b for face (v, a, b)) form one cycle
    let mut next: HashMap<usize, HashMap<usize, usize>> = HashMap::new();
    for f in faces {
        for k in 0..3 {
            next.entry(f[k])
                .or_default()
                .insert(f[(k + 1) % 3], f[(k + 2) % 3]);
        }
    }
    for (v, ring) in &next {
        let start = *ring.keys().next().unwrap();
        let mut at = start;
        let mut n = 0;
        loop {
            at = ring[&at];
            n += 1;
            if at == start || n > ring.len() {
                break;
            }
        }
        if n != ring.len() {
            return Err(format!(
                "the faces round vertex {v} form more than one fan ({n} of {} in the first)",
                ring.len()
            ));
        }
    }
    Ok(())
}

/// Whether the segment p–q meets the triangle (a, b, c), ends and borders included
/// (Möller–Trumbore; a segment parallel to the plane never meets it here: the coplanar
/// case is tested apart).
fn segment_meets_triangle(p: P, q: P, t: [P; 3]) -> bool {
    let dir = sub(q, p);
    let e1 = sub(t[1], t[0]);
    let e2 = sub(t[2], t[0]);
    let h = cross(dir, e2);
    let det = dot(e1, h);
    let scale = norm(dir) * norm(e1) * norm(e2);
    if det.abs() <= 1e-14 * scale {
        return false;
    }
    let s = sub(p, t[0]);
    let u = dot(s, h) / det;
    if !(0.0..=1.0).contains(&u) {
        return false;
    }
    let qv = cross(s, e1);
    let v = dot(dir, qv) / det;
    if v < 0.0 || u + v > 1.0 {
        return false;
    }
    let w = dot(e2, qv) / det;
    (0.0..=1.0).contains(&w)
}

/// Whether two coplanar triangles overlap (in the plane of the first, by 2D tests: an edge
/// crossing an edge, or a corner inside the other).
fn coplanar_overlap(a: [P; 3], b: [P; 3]) -> bool {
    let n = cross(sub(a[1], a[0]), sub(a[2], a[0]));
    let ax = if n[0].abs() >= n[1].abs() && n[0].abs() >= n[2].abs() {
        0
    } else if n[1].abs() >= n[2].abs() {
        1
    } else {
        2
    };
    let (i, j) = ((ax + 1) % 3, (ax + 2) % 3);
    let f = |p: P| [p[i], p[j]];
    let (a2, b2) = (a.map(f), b.map(f));
    let orient = |o: [f64; 2], p: [f64; 2], q: [f64; 2]| {
        (p[0] - o[0]) * (q[1] - o[1]) - (p[1] - o[1]) * (q[0] - o[0])
    };
    let inside = |t: [[f64; 2]; 3], p: [f64; 2]| {
        let s = orient(t[0], t[1], t[2]).signum();
        (0..3).all(|k| orient(t[k], t[(k + 1) % 3], p) * s > 0.0)
    };
    for k in 0..3 {
        for l in 0..3 {
            let (p, q) = (a2[k], a2[(k + 1) % 3]);
            let (r, s) = (b2[l], b2[(l + 1) % 3]);
            let (d1, d2) = (orient(p, q, r), orient(p, q, s));
            let (d3, d4) = (orient(r, s, p), orient(r, s, q));
            if d1 * d2 < 0.0 && d3 * d4 < 0.0 {
                return true;
            }
        }
    }
    a2.iter().any(|&p| inside(b2, p)) || b2.iter().any(|&p| inside(a2, p))
}

/// Whether faces `fa` and `fb` of the mesh meet anywhere but in the vertices and edge they
/// share.
/// Whether all of `b`'s corners lie in the plane of `a` (to rounding).
fn coplanar(a: [P; 3], b: [P; 3]) -> bool {
    let n = cross(sub(a[1], a[0]), sub(a[2], a[0]));
    let nn = norm(n);
    b.iter()
        .all(|&p| dot(sub(p, a[0]), n).abs() <= 1e-12 * nn * norm(sub(p, a[0])).max(1e-300))
}

/// Two coplanar faces sharing a corner: whether they overlap beyond it (shrunk
/// towards their centroids by a millionth, so the shared corner alone does not count).
fn coplanar_overlap_at(a: [P; 3], b: [P; 3]) -> bool {
    let shrink = |t: [P; 3]| {
        let c = mul(add(add(t[0], t[1]), t[2]), 1.0 / 3.0);
        t.map(|p| add(c, mul(sub(p, c), 1.0 - 1e-6)))
    };
    coplanar_overlap(shrink(a), shrink(b))
}

fn faces_meet(v: &[P], fa: [usize; 3], fb: [usize; 3]) -> bool {
    let shared: Vec<usize> = fa.iter().copied().filter(|x| fb.contains(x)).collect();
    let ta = fa.map(|i| v[i]);
    let tb = fb.map(|i| v[i]);
    match shared.len() {
        3 => true,
        2 => {
            // folded onto each other about the shared edge
            let (s0, s1) = (v[shared[0]], v[shared[1]]);
            let e = sub(s1, s0);
            let ee = dot(e, e);
            let off = |p: P| {
                let w = sub(p, s0);
                sub(w, mul(e, dot(w, e) / ee))
            };
            let a = *fa.iter().find(|x| !shared.contains(x)).unwrap();
            let b = *fb.iter().find(|x| !shared.contains(x)).unwrap();
            let (ua, ub) = (off(v[a]), off(v[b]));
            dot(ua, ub) > (1.0 - 1e-12) * norm(ua) * norm(ub)
        }
        1 => {
            let s = shared[0];
            let rest = |f: [usize; 3]| {
                let k = f.iter().position(|&x| x == s).unwrap();
                (v[f[(k + 1) % 3]], v[f[(k + 2) % 3]])
            };
            let (a1, a2) = rest(fa);
            let (b1, b2) = rest(fb);
            // the two triangles' planes meet in a line through the shared vertex; a piece
            // of that line in both ends on an edge of one of them, and an edge from the
            // shared vertex lies in the other's plane only if the faces are coplanar, so
            // testing the far edges is enough (the coplanar case included: then a far edge
            // meets the other face, or the faces are apart)
            segment_meets_triangle(a1, a2, tb)
                || segment_meets_triangle(b1, b2, ta)
                || (coplanar(ta, tb) && coplanar_overlap_at(ta, tb))
        }
        _ => {
            let n = cross(sub(ta[1], ta[0]), sub(ta[2], ta[0]));
            let nn = norm(n);
            let coplanar = tb
                .iter()
                .all(|&p| dot(sub(p, ta[0]), n).abs() <= 1e-12 * nn);
            if coplanar {
                return coplanar_overlap(ta, tb);
            }
            (0..3).any(|k| segment_meets_triangle(ta[k], ta[(k + 1) % 3], tb))
                || (0..3).any(|k| segment_meets_triangle(tb[k], tb[(k + 1) % 3], ta))
        }
    }
}

/// The pairs of faces that meet other than in shared vertices and edges (at most `limit`),
/// found through a uniform grid of the faces' bounding boxes.
pub fn self_intersections(v: &[P], faces: &[[usize; 3]], limit: usize) -> Vec<(usize, usize)> {
    let boxes: Vec<(P, P)> = faces
        .iter()
        .map(|f| {
            let mut lo = v[f[0]];
            let mut hi = v[f[0]];
            for &i in &f[1..] {
                for a in 0..3 {
                    lo[a] = lo[a].min(v[i][a]);
                    hi[a] = hi[a].max(v[i][a]);
                }
            }
            (lo, hi)
        })
        .collect();
    let mean_size = boxes
        .iter()
        .map(|(lo, hi)| norm(sub(*hi, *lo)))
        .sum::<f64>()
        / boxes.len().max(1) as f64;
    let cell = (2.0 * mean_size).max(1e-9);
    let key = |p: P| p.map(|x| (x / cell).floor() as i64);
    let mut grid: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
    for (i, (lo, hi)) in boxes.iter().enumerate() {
        let (a, b) = (key(*lo), key(*hi));
        for x in a[0]..=b[0] {
            for y in a[1]..=b[1] {
                for z in a[2]..=b[2] {
                    grid.entry([x, y, z]).or_default().push(i);
                }
            }
        }
    }
    let mut found = Vec::new();
    for (c, list) in &grid {
        for (k, &i) in list.iter().enumerate() {
            for &j in &list[k + 1..] {
                let (a, b) = (boxes[i], boxes[j]);
                if (0..3).any(|x| a.0[x] > b.1[x] || b.0[x] > a.1[x]) {
                    continue;
                }
                // test each pair once: in the cell of its boxes' common lower corner
                let lo = [0, 1, 2].map(|x| a.0[x].max(b.0[x]));
                if key(lo) != *c {
                    continue;
                }
                if faces_meet(v, faces[i], faces[j]) {
                    found.push((i.min(j), i.max(j)));
                    if found.len() >= limit {
                        return found;
                    }
                }
            }
        }
    }
    found
}

/// The exact distance from `p` to the triangle `t`: to the plane where p's projection falls
/// inside, else to the nearest of its three edges.
pub fn point_triangle_distance(p: P, t: [P; 3]) -> f64 {
    let n = cross(sub(t[1], t[0]), sub(t[2], t[0]));
    let nn = dot(n, n);
    if nn > 0.0 {
        let h = dot(sub(p, t[0]), n) / nn;
        let q = sub(p, mul(n, h));
        let inside = (0..3).all(|k| dot(cross(sub(t[(k + 1) % 3], t[k]), sub(q, t[k])), n) >= 0.0);
        if inside {
            return h.abs() * nn.sqrt();
        }
    }
    (0..3)
        .map(|k| {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            let ab = sub(b, a);
            let l = dot(ab, ab);
            let s = if l > 0.0 {
                (dot(sub(p, a), ab) / l).clamp(0.0, 1.0)
            } else {
                0.0
            };
            norm(sub(p, add(a, mul(ab, s))))
        })
        .fold(f64::INFINITY, f64::min)
}

/// The points of face (a, b, c) that are checked: its corners, edge midpoints, centroid and
/// six more inner points.
pub fn face_samples(t: [P; 3]) -> Vec<P> {
    let bary = [
        (1.0, 0.0, 0.0),
        (0.0, 1.0, 0.0),
        (0.0, 0.0, 1.0),
        (0.5, 0.5, 0.0),
        (0.0, 0.5, 0.5),
        (0.5, 0.0, 0.5),
        (1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0),
        (0.6, 0.2, 0.2),
        (0.2, 0.6, 0.2),
        (0.2, 0.2, 0.6),
        (0.45, 0.45, 0.1),
        (0.1, 0.45, 0.45),
        (0.45, 0.1, 0.45),
    ];
    bary.iter()
        .map(|&(u, v, w)| add(add(mul(t[0], u), mul(t[1], v)), mul(t[2], w)))
        .collect()
}

/// The worst difference between |d| and the distance to `part` over every sample of every
/// face of the mesh, with the point where it is, on all cores.
pub fn worst_distance_error(part: &[[P; 3]], v: &[P], faces: &[[usize; 3]], d: f64) -> (f64, P) {
    let threads = std::thread::available_parallelism().map_or(2, |n| n.get());
    let chunk = faces.len().div_ceil(threads).max(1);
    std::thread::scope(|s| {
        let jobs: Vec<_> = faces
            .chunks(chunk)
            .map(|fs| {
                s.spawn(move || {
                    let mut worst = (0.0f64, [0.0; 3]);
                    for f in fs {
                        let t = f.map(|i| v[i]);
                        // the samples lie within r of the centroid: only a part triangle
                        // within (nearest from the centroid) + 2r can be nearest to one
                        let c = mul(add(add(t[0], t[1]), t[2]), 1.0 / 3.0);
                        let r = t.iter().map(|&p| norm(sub(p, c))).fold(0.0, f64::max);
                        let from_c: Vec<f64> = part
                            .iter()
                            .map(|pt| point_triangle_distance(c, *pt))
                            .collect();
                        let near = from_c.iter().copied().fold(f64::INFINITY, f64::min);
                        let candidates: Vec<&[P; 3]> = part
                            .iter()
                            .zip(&from_c)
                            .filter(|(_, &dc)| dc <= near + 2.0 * r)
                            .map(|(pt, _)| pt)
                            .collect();
                        for p in face_samples(t) {
                            let dist = candidates
                                .iter()
                                .map(|pt| point_triangle_distance(p, **pt))
                                .fold(f64::INFINITY, f64::min);
                            let e = (dist - d.abs()).abs();
                            if e > worst.0 {
                                worst = (e, p);
                            }
                        }
                    }
                    worst
                })
            })
            .collect();
        jobs.into_iter()
            .map(|j| j.join().unwrap())
            .fold((0.0, [0.0; 3]), |a, b| if b.0 > a.0 { b } else { a })
    })
}

/// Whether `p` is inside the closed part (the parity of a ray's crossings, in a direction
/// unlikely to graze an edge).
pub fn inside(part: &[[P; 3]], p: P) -> bool {
    let q = add(p, mul([0.5773, 0.3141, 0.7537], 1e6));
    part.iter()
        .filter(|t| segment_meets_triangle(p, q, **t))
        .count()
        % 2
        == 1
}

/// The enclosed volume of a closed, outward-turned mesh.
pub fn volume(v: &[P], faces: &[[usize; 3]]) -> f64 {
    faces
        .iter()
        .map(|f| dot(v[f[0]], cross(v[f[1]], v[f[2]])) / 6.0)
        .sum()
}

/// The part's surface: its triangles without the pairs two bodies share (the same three
/// corners).
pub fn outer_triangles(part: &[[P; 3]]) -> Vec<[P; 3]> {
    let key = |t: &[P; 3]| {
        let mut k: Vec<[u64; 3]> = t.iter().map(|p| p.map(f64::to_bits)).collect();
        k.sort_unstable();
        k
    };
    let mut count: HashMap<Vec<[u64; 3]>, usize> = HashMap::new();
    for t in part {
        *count.entry(key(t)).or_insert(0) += 1;
    }
    part.iter()
        .filter(|t| count[&key(t)] == 1)
        .copied()
        .collect()
}
