//! Surfaces fitted to measured point grids: a bicubic patch sampled on a grid comes back
//! exactly, tessellations stay within their tolerance, and a hemisphere fitted from its
//! points and finished gives the sphere's exact tool-tip heights within the tolerance
//! plus the fit error.

use crate::mesh_support;

use mesh_support::tip_over_sphere;
use offset_core::mesh::bvh::Bvh;
use offset_core::mesh::surface::{mesh_from_points, read_point_grid, BicubicSurface, PointGrid};
use offset_core::mesh::{finish3d, Cutter, Finish3dParams, MeshError, V3};
use offset_core::ops::Stepover;
use offset_core::toolpath::Move;

/// A known bicubic Bézier patch (not a height field in any obvious way).
fn known_patch(u: f64, v: f64) -> V3 {
    let b = |t: f64| {
        let s = 1.0 - t;
        [s * s * s, 3.0 * s * s * t, 3.0 * s * t * t, t * t * t]
    };
    let (bu, bv) = (b(u), b(v));
    let mut q = V3::ZERO;
    for (k, &wu) in bu.iter().enumerate() {
        for (l, &wv) in bv.iter().enumerate() {
            let c = V3::new(
                10.0 * k as f64 + 1.5 * (l as f64 - 1.5).powi(2),
                8.0 * l as f64 - 2.0 * (k as f64 - 1.0).powi(2),
                3.0 * ((k * 7 + l * 3) % 5) as f64 - 4.0,
            );
            q += c * (wu * wv);
        }
    }
    q
}

fn grid_of(f: impl Fn(f64, f64) -> V3, cols: usize, rows: usize) -> PointGrid {
    let mut points = Vec::new();
    for r in 0..rows {
        for c in 0..cols {
            points.push(f(
                c as f64 / (cols - 1) as f64,
                r as f64 / (rows - 1) as f64,
            ));
        }
    }
    PointGrid { rows, cols, points }
}

#[test]
fn a_fit_to_points_of_a_bicubic_patch_reproduces_the_patch() {
    let (cols, rows) = (7, 6);
    let s = BicubicSurface::fit(&grid_of(known_patch, cols, rows));
    let mut worst: f64 = 0.0;
    for a in 0..=40 {
        for b in 0..=40 {
            let (u, v) = (a as f64 / 40.0, b as f64 / 40.0);
            let q = s.eval(u * (cols - 1) as f64, v * (rows - 1) as f64);
            worst = worst.max(q.dist(known_patch(u, v)));
        }
    }
    assert!(
        worst < 1e-9,
        "the fitted surface strays {worst} mm from the patch"
    );
}

#[test]
fn a_tessellation_stays_within_its_tolerance() {
    let f = |u: f64, v: f64| {
        let (x, y) = (60.0 * u, 40.0 * v);
        V3::new(x, y, 5.0 * (x / 9.0).sin() * (y / 7.0).cos())
    };
    let s = BicubicSurface::fit(&grid_of(f, 31, 21));
    for tol in [0.05, 0.01, 0.002] {
        let m = s.tessellate("wave", tol).unwrap();
        let tris: Vec<[V3; 3]> = m.triangles().collect();
        let bvh = Bvh::new(&tris, false);
        let mut worst: f64 = 0.0;
        for a in 0..=97 {
            for b in 0..=61 {
                let p = s.eval(a as f64 * 30.0 / 97.0, b as f64 * 20.0 / 61.0);
                worst = worst.max(bvh.nearest(&tris, p).0);
            }
        }
        assert!(
            worst <= tol,
            "tolerance {tol}: the surface lies {worst} mm from its tessellation ({} faces)",
            m.faces.len()
        );
    }
}

#[test]
fn a_hemisphere_fitted_from_its_points_and_finished_matches_the_sphere() {
    let rs = 25.0;
    let half = 15.0; // the grid spans [-15, 15]², all of it on the sphere
    let n = 31;
    let sphere_z = |x: f64, y: f64| (rs * rs - x * x - y * y).sqrt();
    let mut csv = String::from("x,y,z\n");
    for r in 0..n {
        for c in 0..n {
            let (x, y) = (
                -half + 2.0 * half * c as f64 / (n - 1) as f64,
                -half + 2.0 * half * r as f64 / (n - 1) as f64,
            );
            csv.push_str(&format!("{x},{y},{}\n", sphere_z(x, y)));
        }
        csv.push('\n');
    }
    let tol = 0.005;
    let (s, m) = mesh_from_points(csv.as_bytes(), "dome.csv", tol).unwrap();
    // the fit's vertical error, measured on a fine sampling of the surface
    let mut fit_err: f64 = 0.0;
    for a in 0..=300 {
        for b in 0..=300 {
            let p = s.eval(
                a as f64 * (n - 1) as f64 / 300.0,
                b as f64 * (n - 1) as f64 / 300.0,
            );
            fit_err = fit_err.max((p.z - sphere_z(p.x, p.y)).abs());
        }
    }
    assert!(fit_err < 1e-3, "fit error {fit_err}");
    let c = Cutter::ball(6.0);
    let p = Finish3dParams {
        cutter: c,
        stepover: Stepover::Mm(1.0),
        tolerance: tol,
        ..Default::default()
    };
    let tp = finish3d(&m, &p).unwrap();
    let mut checked = 0;
    for mv in &tp.moves {
        if let Move::Linear { to, .. } = mv {
            let rho = (to.x * to.x + to.y * to.y).sqrt();
            // where the cutter's footprint lies inside the fitted patch
            if to.x.abs() < half - 3.5 && to.y.abs() < half - 3.5 {
                let exact = tip_over_sphere(&c, rs, rho);
                assert!(
                    (to.z - exact).abs() <= tol + fit_err + 1e-9,
                    "finish over the fitted dome at ({:.3}, {:.3}): tip {} vs exact {exact} (tolerance {tol} + fit error {fit_err:.2e})",
                    to.x,
                    to.y,
                    to.z
                );
                checked += 1;
            }
        }
    }
    assert!(checked > 100, "only {checked} cutter locations checked");
}

#[test]
fn ragged_rows_are_refused_naming_the_row() {
    let csv = b"0,0,0\n1,0,0\n2,0,0\n\n0,1,0\n1,1,0\n";
    let e = read_point_grid(csv, "probe.csv").unwrap_err();
    assert!(
        matches!(
            e,
            MeshError::Ragged {
                row: 2,
                len: 2,
                expected: 3,
                ..
            }
        ),
        "{e}"
    );
    assert_eq!(
        e.to_string(),
        "probe.csv: row 2 (line 5) has 2 points but row 1 has 3: a point grid needs rows of equal length"
    );
}

#[test]
fn a_word_among_the_numbers_is_refused_naming_the_line() {
    let csv = b"x,y,z\n0,0,0\n1,0,oops\n";
    let e = read_point_grid(csv, "probe.csv").unwrap_err().to_string();
    assert_eq!(e, "probe.csv, line 3: \"oops\" is not a number");
}

#[test]
fn a_nan_among_the_numbers_is_refused_naming_the_line() {
    let csv = b"0,0,0\n1,0,NaN\n";
    let e = read_point_grid(csv, "probe.csv").unwrap_err().to_string();
    assert_eq!(e, "probe.csv, line 2: value 3 is not a finite number");
}

#[test]
fn a_line_of_two_values_is_refused() {
    let e = read_point_grid(b"0,0,0\n1,0\n", "probe.csv")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("line 2") && e.contains("3 values a point"),
        "{e}"
    );
}

#[test]
fn a_single_row_is_not_a_grid() {
    let e = read_point_grid(b"0,0,0,1,0,0,2,0,0\n", "probe.csv")
        .unwrap_err()
        .to_string();
    assert!(e.contains("at least 2 rows"), "{e}");
}

#[test]
fn a_fitted_surface_closes_into_a_solid() {
    let f = |u: f64, v: f64| V3::new(20.0 * u, 10.0 * v, 3.0 + (u * 3.0).sin());
    let s = BicubicSurface::fit(&grid_of(f, 9, 5));
    let m = s.solid("block", 0.01, 0.0).unwrap();
    let r = m.report();
    assert!(r.closed, "{r:?}");
    assert!(m.volume() > 0.0);
    let e = s.solid("block", 0.01, 5.0).unwrap_err().to_string();
    assert!(e.contains("must lie below"), "{e}");
}

/// Found by the never-panic property in CI (input ","): a line of separators only
/// held an empty point and the reader indexed it.
#[test]
fn lines_of_separators_only_are_blank_lines() {
    let e = read_point_grid(b",", "probe.csv").unwrap_err().to_string();
    assert_eq!(e, "probe.csv, line 1: holds no points");
    let grid = read_point_grid(b"0,0,0\n1,0,0\n, ,\n0,1,0\n1,1,0\n", "probe.csv").unwrap();
    assert_eq!((grid.rows, grid.cols), (2, 2));
}
