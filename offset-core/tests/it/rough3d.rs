//! Z-level roughing of meshes: every position the tool passes through keeps the stock
//! allowance from the part (judged by an independent drop-cutter of the tool grown by the
//! allowance), levels run from the stock top down to the floor, and parts that are no
//! closed solid (undercuts, holes) are roughed from their upper envelope with a warning.

use offset_core::mesh::shapes::{cube_with_boss, height_field_solid, sphere};
use offset_core::mesh::{rough3d, rough3d_safe_links, Cutter, DropCutter, Mesh, Rough3dParams, V3};
use offset_core::ops::Stepover;
use offset_core::toolpath::{Move, Tool, P3};

/// Checks that the flat tool of `p` keeps `p.stock_allowance` (less `slack`) from `m` at
/// every position of the path, and returns the cutting levels seen.
pub(crate) fn keeps_allowance(case: &str, m: &Mesh, p: &Rough3dParams, slack: f64) -> Vec<f64> {
    let tp = rough3d(m, p).unwrap();
    let a = p.stock_allowance;
    let r = p.tool.radius();
    // the flat tool grown by a ball of radius a is a bull cutter of radius r + a and
    // corner a, its tip a below the tool's; judged `slack` short of it all round (a tool
    // exactly touching a wall with its rim does not cut it)
    let a = a - slack;
    let grown = if a > 0.0 {
        Cutter::bull(2.0 * (r + a), a)
    } else {
        Cutter::flat(2.0 * (r + a))
    };
    let dc = DropCutter::new(m, grown).unwrap();
    let start = match tp.moves.iter().find_map(|mv| match mv {
        Move::Rapid { to } => Some(*to),
        _ => None,
    }) {
        Some(s) => s,
        None => panic!("{case}: the path never moves"),
    };
    let mut levels: Vec<f64> = Vec::new();
    let mut worst = f64::NEG_INFINITY;
    for q in tp.sample(start, 0.5) {
        let need = dc.drop(q.x, q.y, -1e9) + a; // lowest tool tip keeping the allowance
        worst = worst.max(need - q.z);
        assert!(
            q.z >= need - 1e-9,
            "{case}: the tool at ({:.3}, {:.3}, {:.4}) comes closer to the part than the allowance {} less {slack} (by {:.4} mm in height)",
            q.x,
            q.y,
            q.z,
            p.stock_allowance,
            need - q.z
        );
    }
    // the levels cut: the Z of every level feed move across but the links at depth (one
    // that follows a feed straight up: passes never go up)
    let mut rose = false;
    tp.walk(start, |from, mv, to| {
        if let Move::Linear { .. } | Move::Arc { .. } = mv {
            let across = from.xy().dist(to.xy()) > 1e-9;
            let level = across && (from.z - to.z).abs() < 1e-12 && !rose;
            rose = !across && to.z > from.z + 1e-9;
            if level && !levels.iter().any(|z| (z - to.z).abs() < 1e-9) {
                levels.push(to.z);
            }
        } else {
            rose = false;
        }
    });
    levels.sort_by(|a, b| b.total_cmp(a));
    eprintln!(
        "{case}: {} moves, levels {levels:?}, closest approach {worst:.4} mm past the allowance",
        tp.moves.len()
    );
    levels
}

fn params(d: f64, a: f64) -> Rough3dParams {
    Rough3dParams {
        tool: Tool::flat(d),
        stepdown: 3.0,
        stepover: Stepover::Percent(45.0),
        stock_allowance: a,
        tolerance: 0.01,
        ..Default::default()
    }
}

#[test]
fn rough_of_a_cube_with_a_boss_keeps_the_allowance_and_reaches_the_floor() {
    let m = cube_with_boss(30.0, 6.0, 8.0, 32);
    // stock 5 mm wider than the part all round, so there is material down to the floor
    let p = Rough3dParams {
        stock_margin: 5.0,
        ..params(6.0, 0.5)
    };
    let levels = keeps_allowance("cube with boss", &m, &p, 0.02);
    let top = 38.0;
    assert!(
        levels[0] <= top && levels[0] >= top - 3.0 - 1e-9,
        "first level {}",
        levels[0]
    );
    assert!(
        (levels.last().unwrap() - 0.0).abs() < 1e-9,
        "last level {:?}",
        levels.last()
    );
    // a level on the cube's top grown by the allowance clears the flat
    assert!(
        levels.iter().any(|z| (z - 30.5).abs() < 1e-6),
        "no level on the flat at 30.5: {levels:?}"
    );
    for w in levels.windows(2) {
        assert!(
            w[0] - w[1] <= 3.0 + 1e-9,
            "levels {} and {} are more than a step-down apart",
            w[0],
            w[1]
        );
    }
}

#[test]
fn rough_with_no_allowance_keeps_the_tool_off_the_part() {
    let m = cube_with_boss(30.0, 6.0, 8.0, 32);
    let p = Rough3dParams {
        stock_margin: 3.0,
        ..params(4.0, 0.0)
    };
    keeps_allowance("cube with boss, no allowance", &m, &p, 0.01);
}

#[test]
fn rough_leaves_levels_the_part_fills_alone() {
    // stock no wider than the part: below the cube's top there is nothing to clear
    let m = cube_with_boss(30.0, 6.0, 8.0, 32);
    let levels = keeps_allowance(
        "cube with boss in a tight stock",
        &m,
        &params(6.0, 0.5),
        0.02,
    );
    assert!(
        levels.iter().all(|&z| z >= 30.5 - 1e-9),
        "levels below the grown cube's top: {levels:?}"
    );
}

#[test]
fn rough_of_a_wavy_solid_keeps_the_allowance() {
    let m = height_field_solid((0.0, 40.0), (0.0, 30.0), 40, 30, 0.0, |x, y| {
        8.0 + 3.0 * (x / 6.0).sin() * (y / 5.0).cos()
    });
    keeps_allowance("wavy solid", &m, &params(6.0, 0.4), 0.03);
}

#[test]
fn rough_starts_at_the_stock_top_given() {
    let m = cube_with_boss(30.0, 6.0, 8.0, 32);
    let p = Rough3dParams {
        stock_top: Some(41.0),
        ..params(6.0, 0.5)
    };
    let levels = keeps_allowance("cube with boss under a higher stock", &m, &p, 0.02);
    assert!(
        levels[0] > 38.0,
        "the first level {} should clear the stock above the part",
        levels[0]
    );
}

#[test]
fn an_undercut_is_roughed_from_the_upper_envelope_with_a_warning() {
    let m = sphere(V3::new(0.0, 0.0, 10.0), 10.0, 16, 32);
    let p = params(6.0, 0.5);
    let tp = rough3d(&m, &p).unwrap();
    assert!(
        tp.warnings
            .iter()
            .any(|w| w.contains("undercut") && w.contains("upper envelope")),
        "{:?}",
        tp.warnings
    );
    // under the equator nothing is cut: the envelope holds the sphere's shadow
    keeps_allowance("sphere from its envelope", &m, &p, 1e-6);
    // above the equator the sphere is a dome: roughed from its sections, no warning
    let p = Rough3dParams {
        floor: Some(10.0),
        ..params(6.0, 0.5)
    };
    let tp = rough3d(&m, &p).unwrap();
    assert!(tp.warnings.is_empty(), "{:?}", tp.warnings);
    let lowest = tp
        .moves
        .iter()
        .filter_map(|mv| match mv {
            Move::Linear { to, .. } => Some(to.z),
            _ => None,
        })
        .fold(f64::INFINITY, f64::min);
    assert!((lowest - 10.0).abs() < 1e-9, "lowest cut at {lowest}");
}

#[test]
fn an_open_mesh_is_roughed_with_one_warning_naming_its_holes() {
    let mut m = cube_with_boss(30.0, 6.0, 8.0, 16);
    m.faces.truncate(m.faces.len() - 1);
    let p = params(6.0, 0.5);
    let tp = rough3d(&m, &p).unwrap();
    assert_eq!(tp.warnings.len(), 1, "{:?}", tp.warnings);
    assert!(
        tp.warnings[0].contains("is open: 3 boundary edges"),
        "{}",
        tp.warnings[0]
    );
    keeps_allowance("cube with boss, one face missing", &m, &p, 1e-6);
}

#[test]
fn safe_link_rough_paths_retract_between_levels() {
    // the rough as planned before links at depth (`rough3d_safe_links`, the comparison of
    // rough_links.rs); with links at depth a level change goes through what the level
    // above cleared instead, which rough_links.rs checks by simulation
    let m = cube_with_boss(30.0, 6.0, 8.0, 16);
    let p = params(6.0, 0.5);
    let tp = rough3d_safe_links(&m, &p).unwrap();
    let safe = 38.0 + p.safe_z;
    // every change of level passes through the safe height
    let mut last_cut: Option<P3> = None;
    let mut up_since = false;
    for mv in &tp.moves {
        match mv {
            Move::Rapid { to } if to.z >= safe - 1e-9 => up_since = true,
            Move::Linear { to, .. } | Move::Arc { to, .. } => {
                if let Some(l) = last_cut {
                    if (l.z - to.z).abs() > 1e-9 && to.z < l.z {
                        // a plunge to a new level: it came from the safe height
                        assert!(
                            up_since || (l.x - to.x).abs() + (l.y - to.y).abs() < 1e-9,
                            "a level change at ({}, {}) without a retract",
                            to.x,
                            to.y
                        );
                    }
                }
                last_cut = Some(*to);
                up_since = false;
            }
            _ => {}
        }
    }
}
