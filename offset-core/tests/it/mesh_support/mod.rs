//! Shared helpers of the 3D tests: tessellations that lie on a known side of an exact
//! surface (so a drop-cutter over them is never below the exact answer), and the exact
//! tool-tip heights over spheres, cylinders and planes.
#![allow(dead_code)]

use offset_core::mesh::shapes::{height_field, revolve};
use offset_core::mesh::v3::dist_to_triangle;
use offset_core::mesh::{Cutter, Mesh, V3};
use std::f64::consts::PI;

/// The upper half of a sphere of radius `rs` about the origin (rim on z = 0), scaled out
/// so that every triangle lies outside the sphere; returns the mesh and how far outside
/// it reaches at most (the tessellation error).
pub fn dome_outside(rs: f64, rings: usize, segments: usize) -> (Mesh, f64) {
    let profile: Vec<(f64, f64)> = (0..=rings)
        .map(|j| {
            let phi = 0.5 * PI * j as f64 / rings as f64;
            let r = rs * phi.sin();
            (if j == 0 { 0.0 } else { r }, rs * phi.cos())
        })
        .collect();
    let mut m = revolve(0.0, 0.0, &profile, segments);
    let inner = m
        .triangles()
        .map(|t| dist_to_triangle(V3::ZERO, &t))
        .fold(f64::INFINITY, f64::min);
    let k = rs / inner;
    for v in &mut m.vertices {
        *v = *v * k;
    }
    let outer = m.vertices.iter().map(|v| v.len()).fold(0.0, f64::max);
    m.name = "dome".into();
    (m, outer - rs)
}

/// The lower half of a sphere of radius `rs` about (0, 0, `zc`) (a bowl, rim on z = zc),
/// vertices on the sphere so every triangle lies inside it; returns the mesh and how far
/// inside it reaches at most.
pub fn bowl_inside(rs: f64, zc: f64, rings: usize, segments: usize) -> (Mesh, f64) {
    let profile: Vec<(f64, f64)> = (0..=rings)
        .map(|j| {
            let phi = 0.5 * PI * j as f64 / rings as f64;
            (
                if j == 0 { 0.0 } else { rs * phi.sin() },
                zc - rs * phi.cos(),
            )
        })
        .collect();
    let mut m = revolve(0.0, 0.0, &profile, segments);
    let c = V3::new(0.0, 0.0, zc);
    let inner = m
        .triangles()
        .map(|t| dist_to_triangle(c, &t))
        .fold(f64::INFINITY, f64::min);
    m.name = "bowl".into();
    (m, rs - inner)
}

/// The upper half of a cylinder of radius `rc` along X (axis on y = z = 0), from x = -len
/// to len, its facets tangent to the cylinder (so outside it); returns the mesh and how far
/// outside it reaches at most.
pub fn half_cylinder_outside(rc: f64, len: f64, steps: usize) -> (Mesh, f64) {
    let da = PI / steps as f64;
    let rho = rc / (da / 2.0).cos();
    let m = height_field((-len, len), (0.0, PI), 1, steps, |_, a| a);
    let mut m = Mesh::new(
        "half cylinder",
        m.vertices
            .iter()
            .map(|v| {
                let a = PI - v.y; // y from +rho to -rho as the grid's j grows
                V3::new(v.x, rho * a.cos(), rho * a.sin())
            })
            .collect(),
        m.faces,
    );
    m.name = "half cylinder".into();
    (m, rho - rc)
}

/// The exact tip height of `c` over (0, ρ) against a sphere of radius `rs` about the
/// origin, contact on its upper half.
pub fn tip_over_sphere(c: &Cutter, rs: f64, rho: f64) -> f64 {
    // the corner circle's centre ring: R - r from the axis; the corner centre nearest the
    // sphere's axis lies at ρ - (R - r) from it, rs + r from its centre
    let (rr, r) = (c.radius(), c.corner());
    let q = (rho - (rr - r)).max(0.0);
    if rho <= rr - r {
        return rs; // the flat bottom sits on the pole
    }
    ((rs + r).powi(2) - q * q).sqrt() - r
}

/// The exact tip height of a ball of radius `r` at distance ρ from the axis of a bowl of
/// radius `rs` about (0, 0, zc).
pub fn tip_in_bowl(r: f64, rs: f64, zc: f64, rho: f64) -> f64 {
    zc - ((rs - r).powi(2) - rho * rho).sqrt() - r
}

/// The exact tip height of `c` over (x, y0) against a cylinder of radius `rc` along X
/// (axis at y = z = 0), contact on its upper half.
pub fn tip_over_cylinder(c: &Cutter, rc: f64, y0: f64) -> f64 {
    let (rr, r) = (c.radius(), c.corner());
    let off = y0.abs() - (rr - r);
    if off <= 0.0 {
        return rc;
    }
    ((rc + r).powi(2) - off * off).sqrt() - r
}

/// The exact tip height of `c` over (x, y) against the plane z = a x + b y + k.
pub fn tip_over_plane(c: &Cutter, a: f64, b: f64, k: f64, x: f64, y: f64) -> f64 {
    let g = (a * a + b * b).sqrt();
    let (rr, r) = (c.radius(), c.corner());
    a * x + b * y + k + (rr - r) * g + r * ((1.0 + g * g).sqrt() - 1.0)
}

/// The three cutters every exact case runs: ball, flat and bull of one diameter.
pub fn cutters(d: f64) -> [Cutter; 3] {
    [Cutter::ball(d), Cutter::flat(d), Cutter::bull(d, d / 5.0)]
}

/// How deep `c` with its tip at `tip` reaches into triangle `t`, judged at a dense grid of
/// the triangle's points (corners and edges included): the largest p.z − h(q) − tip over
/// those points within the cutter's radius (negative when clear).
pub fn penetration(c: &Cutter, tip: V3, t: &[V3; 3], n: usize) -> f64 {
    let mut worst = f64::NEG_INFINITY;
    let rr = c.radius();
    for i in 0..=n {
        for j in 0..=(n - i) {
            let (u, v) = (i as f64 / n as f64, j as f64 / n as f64);
            let p = t[0] + (t[1] - t[0]) * u + (t[2] - t[0]) * v;
            let q = ((p.x - tip.x).powi(2) + (p.y - tip.y).powi(2)).sqrt();
            if q <= rr {
                worst = worst.max(p.z - c.profile(q) - tip.z);
            }
        }
    }
    // the edges more densely
    for k in 0..3 {
        let (a, b) = (t[k], t[(k + 1) % 3]);
        for s in 0..=8 * n {
            let p = a.lerp(b, s as f64 / (8 * n) as f64);
            let q = ((p.x - tip.x).powi(2) + (p.y - tip.y).powi(2)).sqrt();
            if q <= rr {
                worst = worst.max(p.z - c.profile(q) - tip.z);
            }
        }
    }
    worst
}
