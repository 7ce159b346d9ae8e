//! Drop-cutter finishing: every cutter location the path stops at is the drop-cutter
//! height there (gouge-free by construction), the path between them stays within the
//! tolerance of the drop-cutter surface (measured square to each move), rows lie a step-over apart in the direction asked
//! for, and line fitting keeps flat stretches to single moves.

use crate::mesh_support;

use mesh_support::dome_outside;
use offset_core::mesh::shapes::height_field;
use offset_core::mesh::{finish3d, Cutter, DropCutter, Finish3dParams, Mesh};
use offset_core::ops::Stepover;
use offset_core::toolpath::{Move, P3};

fn params(c: Cutter) -> Finish3dParams {
    Finish3dParams {
        cutter: c,
        stepover: Stepover::Mm(1.5),
        tolerance: 0.01,
        ..Default::default()
    }
}

fn cut_points(tp: &offset_core::toolpath::Toolpath) -> Vec<P3> {
    tp.moves
        .iter()
        .filter_map(|m| match m {
            Move::Linear { to, .. } => Some(*to),
            _ => None,
        })
        .collect()
}

fn stays_on_the_drop_surface(case: &str, m: &Mesh, p: &Finish3dParams) {
    let tp = finish3d(m, p).unwrap();
    let dc = DropCutter::new(m, p.cutter).unwrap();
    let floor = m.bounds().unwrap().0.z;
    for q in cut_points(&tp) {
        let z = dc.drop(q.x, q.y, floor);
        assert!(
            (q.z - z).abs() < 1e-9,
            "{case}: a cutter location at ({}, {}) has Z {} but the drop-cutter height is {z}",
            q.x,
            q.y,
            q.z
        );
    }
    // between locations, along every cutting move
    let start = P3::new(0.0, 0.0, 1e3);
    let mut worst_below: f64 = 0.0;
    let mut worst_above: f64 = 0.0;
    let mut pos = start;
    for mv in &tp.moves {
        match mv {
            Move::Linear { to, .. } => {
                let n = ((pos.dist(*to) / 0.05).ceil() as usize).max(1);
                if pos.z < 1e2 && (pos.x != to.x || pos.y != to.y) {
                    for k in 1..n {
                        let t = k as f64 / n as f64;
                        let q = P3::new(
                            pos.x + (to.x - pos.x) * t,
                            pos.y + (to.y - pos.y) * t,
                            pos.z + (to.z - pos.z) * t,
                        );
                        let z = dc.drop(q.x, q.y, floor);
                        // measured square to the move (a steep move's height error is
                        // mostly along it)
                        let run = ((to.x - pos.x).powi(2) + (to.y - pos.y).powi(2)).sqrt();
                        let square = run / pos.dist(*to);
                        worst_below = worst_below.max((z - q.z) * square);
                        worst_above = worst_above.max((q.z - z) * square);
                    }
                }
                pos = *to;
            }
            Move::Rapid { to } => pos = *to,
            _ => {}
        }
    }
    assert!(
        worst_below <= p.tolerance,
        "{case}: between cutter locations the path dips {worst_below} mm into the drop-cutter surface (tolerance {})",
        p.tolerance
    );
    assert!(
        worst_above <= 2.0 * p.tolerance,
        "{case}: between cutter locations the path rides {worst_above} mm above the drop-cutter surface"
    );
}

#[test]
fn a_ball_finish_of_a_dome_stays_on_the_drop_cutter_surface() {
    let (m, _) = dome_outside(20.0, 24, 48);
    stays_on_the_drop_surface("dome, ball", &m, &params(Cutter::ball(6.0)));
}

#[test]
fn a_bull_finish_of_a_dome_at_30_degrees_stays_on_the_drop_cutter_surface() {
    let (m, _) = dome_outside(20.0, 24, 48);
    let p = Finish3dParams {
        angle: 30.0,
        ..params(Cutter::bull(6.0, 1.0))
    };
    stays_on_the_drop_surface("dome, bull at 30°", &m, &p);
}

#[test]
fn a_flat_finish_of_a_wavy_field_without_zigzag_stays_on_the_drop_cutter_surface() {
    let m = height_field((0.0, 30.0), (0.0, 20.0), 30, 20, |x, y| {
        2.0 * (x / 4.0).sin() * (y / 5.0).cos()
    });
    let p = Finish3dParams {
        zigzag: false,
        ..params(Cutter::flat(4.0))
    };
    stays_on_the_drop_surface("wavy field, flat, one way", &m, &p);
}

#[test]
fn rows_lie_a_step_over_apart_in_the_direction_asked() {
    let m = height_field((0.0, 30.0), (0.0, 20.0), 3, 2, |_, _| 1.0);
    for (angle, along_x) in [(0.0, true), (90.0, false)] {
        let p = Finish3dParams {
            angle,
            ..params(Cutter::ball(4.0))
        };
        let tp = finish3d(&m, &p).unwrap();
        let pts = cut_points(&tp);
        let mut across: Vec<f64> = pts
            .iter()
            .map(|q| if along_x { q.y } else { q.x })
            .collect();
        across.sort_by(f64::total_cmp);
        across.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
        let width = if along_x { 20.0 } else { 30.0 };
        assert!(
            (across[0] - 0.0).abs() < 1e-9 && (across[across.len() - 1] - width).abs() < 1e-9,
            "angle {angle}: rows from {} to {}",
            across[0],
            across[across.len() - 1]
        );
        for w in across.windows(2) {
            assert!(
                w[1] - w[0] <= 1.5 + 1e-9,
                "angle {angle}: rows {} and {} are more than a step-over apart",
                w[0],
                w[1]
            );
        }
    }
}

#[test]
fn a_flat_plane_finishes_in_one_move_a_row() {
    let m = height_field((0.0, 30.0), (0.0, 20.0), 12, 8, |x, y| {
        0.1 * x - 0.05 * y + 2.0
    });
    // the cutter kept off the plane's edges, where it would hang over
    let p = Finish3dParams {
        area: Some([3.0, 0.0, 27.0, 20.0]),
        ..params(Cutter::ball(4.0))
    };
    let tp = finish3d(&m, &p).unwrap();
    let rows = (20.0f64 / 1.5).ceil() as usize + 1;
    // the rows along the plane's bottom and top edges still hang over: three moves each
    let linears = cut_points(&tp).len();
    // per row: one move along it; between rows: one link (zigzag); plus the first plunge
    assert!(
        linears <= 2 * rows + 1 + 8,
        "{linears} cutting moves for {rows} rows"
    );
}

#[test]
fn the_path_starts_and_ends_at_the_safe_height_with_the_tool_named() {
    let (m, _) = dome_outside(20.0, 12, 24);
    let p = params(Cutter::ball(6.0));
    let tp = finish3d(&m, &p).unwrap();
    let safe = m.bounds().unwrap().1.z + p.safe_z;
    let first = tp
        .moves
        .iter()
        .find_map(|mv| match mv {
            Move::Rapid { to } => Some(*to),
            _ => None,
        })
        .unwrap();
    let last = tp
        .moves
        .iter()
        .rev()
        .find_map(|mv| match mv {
            Move::Rapid { to } => Some(*to),
            _ => None,
        })
        .unwrap();
    assert!((first.z - safe).abs() < 1e-9 && (last.z - safe).abs() < 1e-9);
    let tool = tp.tool.unwrap();
    assert_eq!(tool.kind, offset_core::toolpath::ToolKind::BallEnd);
    assert_eq!(tool.diameter, 6.0);
}

#[test]
fn bad_finishing_parameters_are_refused_by_name() {
    let (m, _) = dome_outside(20.0, 12, 24);
    let cases = [
        (
            Finish3dParams {
                stepover: Stepover::Mm(8.0),
                ..params(Cutter::ball(6.0))
            },
            "more than the cutter diameter",
        ),
        (
            Finish3dParams {
                tolerance: 0.0,
                ..params(Cutter::ball(6.0))
            },
            "the tolerance must be a positive number",
        ),
        (params(Cutter::bull(6.0, 4.0)), "corner radius"),
        (params(Cutter::flat(f64::NAN)), "the cutter diameter"),
    ];
    for (p, want) in cases {
        let e = finish3d(&m, &p).unwrap_err().to_string();
        assert!(e.contains(want), "{e}");
    }
}

#[test]
fn ball_waterlines_round_a_sphere_lie_at_the_exact_radius() {
    use offset_core::mesh::shapes::sphere;
    use offset_core::mesh::{waterline3d, WaterlineParams, V3};
    // a sphere of radius 15 about (0, 0, 15), its facets pushed out so they lie outside it
    let rs = 15.0;
    let mut m = sphere(V3::new(0.0, 0.0, 0.0), rs, 48, 96);
    let inner = m
        .triangles()
        .map(|t| offset_core::mesh::v3::dist_to_triangle(V3::ZERO, &t))
        .fold(f64::INFINITY, f64::min);
    let eps = m.vertices.iter().map(|v| v.len()).fold(0.0, f64::max) * rs / inner - rs;
    for v in &mut m.vertices {
        *v = *v * (rs / inner) + V3::new(0.0, 0.0, rs);
    }
    let r = 3.0;
    let p = WaterlineParams {
        cutter: Cutter::ball(2.0 * r),
        stepdown: 2.0,
        tolerance: 0.01,
        floor: Some(rs),
        ..Default::default()
    };
    let tp = waterline3d(&m, &p).unwrap();
    let mut n = 0;
    for q in cut_points(&tp) {
        // the ball's centre is rs + r from the sphere's centre (within the tolerance of
        // the offset the contours come from, and the facets' distance outside the sphere)
        let d = V3::new(q.x, q.y, q.z + r - rs).len();
        assert!(
            d >= rs + r - p.tolerance - 1e-9 && d <= rs + r + eps + p.tolerance,
            "waterline at Z {}: the ball's centre is {d} from the sphere's, exact {} (tessellation {eps}, tolerance {})",
            q.z,
            rs + r,
            p.tolerance
        );
        n += 1;
    }
    assert!(n > 100, "only {n} points");
}
