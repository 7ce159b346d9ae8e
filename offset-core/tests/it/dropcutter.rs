//! Drop-cutter against exact answers: over tessellations that lie on the material's side
//! of a sphere, a bowl, a cylinder or a plane, the tool tip is never below the exact
//! height and no more above it than the tessellation error allows; and, for random meshes
//! and cutters, no cutter location lets the cutter into any triangle.

use crate::mesh_support;

use mesh_support::*;
use offset_core::mesh::{Cutter, DropCutter, Mesh, V3};
use proptest::prelude::*;

/// Runs `c` over the points `(x, y)` and checks each tip against [lo, hi] from `exact`.
fn check_band(
    case: &str,
    m: &Mesh,
    c: Cutter,
    pts: &[(f64, f64)],
    lo: impl Fn(f64, f64) -> f64,
    hi: impl Fn(f64, f64) -> f64,
) {
    let dc = DropCutter::new(m, c).unwrap();
    let mut worst_above: f64 = 0.0;
    for &(x, y) in pts {
        let z = dc.drop(x, y, -1e6);
        let (l, h) = (lo(x, y), hi(x, y));
        assert!(
            z >= l - 1e-9,
            "{case}, {:?} d{}: tip {z} at ({x}, {y}) is {} below the exact {l}",
            c.shape,
            c.diameter,
            l - z
        );
        assert!(
            z <= h + 1e-9,
            "{case}, {:?} d{}: tip {z} at ({x}, {y}) is {} above the bound {h} (exact {l})",
            c.shape,
            c.diameter,
            z - h
        );
        worst_above = worst_above.max(z - l);
    }
    assert!(worst_above.is_finite(), "{case}: no points");
}

fn radial_points(rmax: f64, n: usize) -> Vec<(f64, f64)> {
    (0..n)
        .map(|i| {
            let rho = rmax * i as f64 / (n - 1) as f64;
            let a = 0.7 + 2.3 * i as f64; // spread round the axis, off the mesh's seams
            (rho * a.cos(), rho * a.sin())
        })
        .collect()
}

#[test]
fn ball_over_a_hemisphere_is_never_below_the_sphere_and_within_the_tessellation_error() {
    let rs = 20.0;
    let (m, eps) = dome_outside(rs, 48, 96);
    assert!(eps < 0.02, "tessellation error {eps}");
    let c = Cutter::ball(6.0);
    let rho = |x: f64, y: f64| (x * x + y * y).sqrt();
    check_band(
        "hemisphere r20",
        &m,
        c,
        &radial_points(18.0, 200),
        |x, y| tip_over_sphere(&c, rs, rho(x, y)),
        |x, y| tip_over_sphere(&c, rs + eps, rho(x, y)),
    );
}

#[test]
fn flat_and_bull_over_a_hemisphere_are_never_below_the_sphere() {
    let rs = 20.0;
    let (m, eps) = dome_outside(rs, 48, 96);
    for c in [Cutter::flat(6.0), Cutter::bull(6.0, 1.0)] {
        let rho = |x: f64, y: f64| (x * x + y * y).sqrt();
        check_band(
            "hemisphere r20",
            &m,
            c,
            &radial_points(15.0, 150),
            |x, y| tip_over_sphere(&c, rs, rho(x, y)),
            |x, y| tip_over_sphere(&c, rs + eps, rho(x, y)),
        );
    }
}

#[test]
fn ball_in_a_bowl_is_never_below_the_sphere_and_within_the_tessellation_error() {
    let (rs, zc) = (25.0, 30.0);
    let (m, eps) = bowl_inside(rs, zc, 48, 96);
    assert!(eps < 0.05, "tessellation error {eps}");
    let r = 4.0;
    let rho = |x: f64, y: f64| (x * x + y * y).sqrt();
    check_band(
        "bowl r25",
        &m,
        Cutter::ball(2.0 * r),
        &radial_points(rs - r - 1.0, 200),
        |x, y| tip_in_bowl(r, rs, zc, rho(x, y)),
        |x, y| tip_in_bowl(r, rs - eps, zc, rho(x, y)),
    );
}

#[test]
fn ball_over_a_cylinder_is_never_below_it_and_within_the_tessellation_error() {
    cylinder_case(Cutter::ball(6.0));
}

#[test]
fn flat_over_a_cylinder_is_never_below_it_and_within_the_tessellation_error() {
    cylinder_case(Cutter::flat(6.0));
}

#[test]
fn bull_over_a_cylinder_is_never_below_it_and_within_the_tessellation_error() {
    cylinder_case(Cutter::bull(6.0, 1.5));
}

fn cylinder_case(c: Cutter) {
    let rc = 15.0;
    let (m, eps) = half_cylinder_outside(rc, 40.0, 120);
    assert!(eps < 0.01, "tessellation error {eps}");
    let pts: Vec<(f64, f64)> = (0..201)
        .map(|i| (-20.0 + 0.173 * i as f64, -16.0 + 0.16 * i as f64))
        .collect();
    check_band(
        "half cylinder r15",
        &m,
        c,
        &pts,
        |_, y| tip_over_cylinder(&c, rc, y),
        |_, y| tip_over_cylinder(&c, rc + eps, y),
    );
}

#[test]
fn ball_flat_and_bull_over_a_tilted_plane_are_exact() {
    let (a, b, k) = (0.3, -0.45, 2.0);
    let m = offset_core::mesh::shapes::height_field((-50.0, 50.0), (-50.0, 50.0), 7, 5, |x, y| {
        a * x + b * y + k
    });
    for c in cutters(6.0) {
        let pts: Vec<(f64, f64)> = (0..100)
            .map(|i| (-40.0 + 0.81 * i as f64, 35.0 - 0.67 * i as f64))
            .collect();
        check_band(
            "tilted plane",
            &m,
            c,
            &pts,
            |x, y| tip_over_plane(&c, a, b, k, x, y),
            |x, y| tip_over_plane(&c, a, b, k, x, y),
        );
    }
}

#[test]
fn ball_flat_and_bull_over_a_level_plane_sit_on_it() {
    let m =
        offset_core::mesh::shapes::height_field((-50.0, 50.0), (-50.0, 50.0), 6, 6, |_, _| 3.25);
    for c in cutters(5.0) {
        let dc = DropCutter::new(&m, c).unwrap();
        for i in 0..50 {
            let (x, y) = (-45.0 + 1.9 * i as f64, 40.0 - 1.7 * i as f64);
            let z = dc.drop(x, y, -1e6);
            assert!(
                (z - 3.25).abs() < 1e-12,
                "level plane, {:?}: tip {z} at ({x}, {y}) instead of 3.25",
                c.shape
            );
        }
    }
}

#[test]
fn ball_location_follows_the_contact_point_and_the_surface_normal() {
    // r_L = r_c + R (N - u): the tip is the contact point moved by R along the surface
    // normal there, less R along the tool axis; on a finely meshed sphere N is the
    // sphere's normal at the contact point to within the facets' tilt
    let rs = 20.0;
    let (m, _) = dome_outside(rs, 96, 192);
    let r = 3.0;
    let dc = DropCutter::new(&m, Cutter::ball(2.0 * r)).unwrap();
    for (x, y) in radial_points(17.0, 60) {
        let ct = dc.drop_contact(x, y, -1e6);
        let cc = ct.cc.expect("the dome is under the cutter");
        // the facet's own normal: the ball centre less the contact point, over R
        let centre = ct.tip + V3::new(0.0, 0.0, r);
        let n_facet = (centre - cc) / r;
        assert!(
            (n_facet.len() - 1.0).abs() < 1e-9,
            "ball at ({x}, {y}): contact {cc:?} is {} from the centre, not R",
            (centre - cc).len()
        );
        let rl = cc + (n_facet - V3::Z) * r;
        assert!(
            rl.dist(ct.tip) < 1e-9,
            "ball at ({x}, {y}): r_L {rl:?} vs tip {:?}",
            ct.tip
        );
        let n_sphere = cc.unit();
        assert!(
            n_facet.dot(n_sphere) > (0.03f64).cos(),
            "ball at ({x}, {y}): contact normal {n_facet:?} is off the sphere's {n_sphere:?}"
        );
    }
}

fn brute_drop(m: &Mesh, c: Cutter, x: f64, y: f64, floor: f64) -> f64 {
    // the same cutter against one triangle at a time, no hierarchy: the largest answer
    let mut z = floor;
    for f in 0..m.faces.len() {
        let one = Mesh::new("one", m.triangle(f).to_vec(), vec![[0, 1, 2]]);
        z = z.max(DropCutter::new(&one, c).unwrap().drop(x, y, floor));
    }
    z
}

fn arb_cutter() -> impl Strategy<Value = Cutter> {
    (0usize..3, 0.5f64..12.0, 0.05f64..1.0).prop_map(|(k, d, f)| match k {
        0 => Cutter::ball(d),
        1 => Cutter::flat(d),
        _ => Cutter::bull(d, (d / 2.0) * f),
    })
}

fn arb_mesh() -> impl Strategy<Value = Mesh> {
    let p = || (-10.0f64..10.0, -10.0f64..10.0, -5.0f64..5.0);
    prop::collection::vec((p(), p(), p()), 1..25).prop_map(|ts| {
        let mut vs = Vec::new();
        let mut fs = Vec::new();
        for (a, b, c) in ts {
            let i = vs.len() as u32;
            for q in [a, b, c] {
                vs.push(V3::new(q.0, q.1, q.2));
            }
            fs.push([i, i + 1, i + 2]);
        }
        Mesh::new("random", vs, fs)
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(offset_core::check::proptest_cases(128)))]

    /// No cutter location lets the cutter into any triangle by more than 1e-9 mm, and the
    /// hierarchy's pruning finds the same height as every triangle tried alone.
    #[test]
    fn no_cutter_location_penetrates_a_triangle(
        m in arb_mesh(),
        c in arb_cutter(),
        pts in prop::collection::vec((-12.0f64..12.0, -12.0f64..12.0), 1..6),
    ) {
        prop_assume!(m.area() > 1e-6);
        let dc = DropCutter::new(&m, c).unwrap();
        for (x, y) in pts {
            let z = dc.drop(x, y, -100.0);
            let tip = V3::new(x, y, z);
            for f in 0..m.faces.len() {
                let t = m.triangle(f);
                let pen = penetration(&c, tip, &t, 40);
                prop_assert!(pen <= 1e-9, "{:?} d{} r{} at ({x}, {y}) tip {z}: face {f} penetrated by {pen}", c.shape, c.diameter, c.corner(), );
            }
            let b = brute_drop(&m, c, x, y, -100.0);
            prop_assert!((b - z).abs() <= 1e-12 * (1.0 + z.abs()), "hierarchy {z} vs one at a time {b}");
            // a ball's centre is exactly R from the nearest triangle where it touches one
            if c.shape == offset_core::mesh::CutterShape::Ball && z > -100.0 {
                let centre = V3::new(x, y, z + c.radius());
                let d = m.triangles().map(|t| offset_core::mesh::v3::dist_to_triangle(centre, &t)).fold(f64::INFINITY, f64::min);
                prop_assert!((d - c.radius()).abs() < 1e-9, "ball centre {d} from the mesh, radius {}", c.radius());
            }
        }
    }
}
