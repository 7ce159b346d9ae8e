//! Links at depth in 3D roughing: on a cube with a boss, a wavy solid and a sphere roughed
//! from its upper envelope, the rough retracts to the safe height fewer times than with
//! every link at the safe height (both counts printed), and the cutting simulation (a
//! height map of the stock block) shows every link moving through air only: no link
//! removes material, no rapid goes through material, and both programs remove the same
//! material. That no position comes nearer the part than the allowance is checked by an
//! independent drop-cutter (`rough3d::keeps_allowance`) on the program with links.

use crate::common::{assert_same_removal, level_at_any};
use offset_core::cutsim::{retracts, simulate, MoveKind, SimOptions, Stock};
use offset_core::geom::Point;
use offset_core::mesh::shapes::{cube_with_boss, height_field_solid, sphere};
use offset_core::mesh::{rough3d, rough3d_safe_links, Mesh, Rough3dParams, V3};
use offset_core::ops::pocket::LINK_LIFT;
use offset_core::ops::Stepover;
use offset_core::stats::Kinematics;
use offset_core::toolpath::{Move, Tool, Toolpath};

fn params(margin: f64) -> Rough3dParams {
    Rough3dParams {
        tool: Tool::flat(6.0),
        stepdown: 3.0,
        stepover: Stepover::Percent(45.0),
        stock_allowance: 0.5,
        stock_margin: margin,
        tolerance: 0.01,
        ..Default::default()
    }
}

/// The Z of every level feed move with some length (passes and links alike).
fn level_heights(tp: &Toolpath) -> Vec<f64> {
    let mut hs: Vec<f64> = Vec::new();
    tp.walk(Default::default(), |from, mv, to| {
        if let Move::Linear { .. } | Move::Arc { .. } = mv {
            if (from.z - to.z).abs() < 1e-12
                && from.xy().dist(to.xy()) > 1e-9
                && !hs.iter().any(|h| (h - to.z).abs() < 1e-9)
            {
                hs.push(to.z);
            }
        }
    });
    hs
}

fn check(name: &str, m: &Mesh, p: &Rough3dParams) {
    let low = rough3d(m, p).unwrap();
    let high = rough3d_safe_links(m, p).unwrap();
    let (n_low, n_high) = (retracts(&low), retracts(&high));
    let k = Kinematics::default();
    let (s_low, s_high) = (low.stats(&k), high.stats(&k));
    let (lo, hi) = m.bounds().unwrap();
    let top = p.stock_top.unwrap_or(hi.z);
    let g = p.stock_margin;
    let stock = Stock::block(
        Point::new(lo.x - g, lo.y - g),
        Point::new(hi.x + g, hi.y + g),
        top,
    );
    let o = SimOptions {
        cell: 0.1,
        ..SimOptions::new(p.tool)
    };
    let r_low = simulate(&low, &stock, &o).unwrap();
    let r_high = simulate(&high, &stock, &o).unwrap();
    let plunged = |r: &offset_core::cutsim::Report| -> f64 {
        r.moves
            .iter()
            .filter(|m| m.kind == MoveKind::Plunge)
            .map(|m| m.removed)
            .sum()
    };
    eprintln!(
        "{name}: {n_high} retracts, rapids {:.0} mm, {:.1} s, {:.0} mm³ removed ({:.0} by plunges) with every link at the safe height; {n_low} retracts, rapids {:.0} mm, {:.1} s, {:.0} mm³ removed ({:.0} by plunges) with links at depth",
        s_high.rapid_length,
        s_high.time(),
        r_high.removed,
        plunged(&r_high),
        s_low.rapid_length,
        s_low.time(),
        r_low.removed,
        plunged(&r_low),
    );
    assert!(
        n_low < n_high,
        "{name}: {n_low} retracts with links at depth, {n_high} without"
    );
    assert_eq!(r_low.rapid_cuts, 0, "{name}: a rapid through material");
    assert_eq!(
        r_high.rapid_cuts, 0,
        "{name}: a rapid through material (safe links)"
    );
    // the same material goes (to a cell's column of a pass's rim: 0.1 % of the volume)
    assert_same_removal(name, r_low.removed, r_high.removed);
    // the entries go down from the floor above: straight plunges remove no more than before
    assert!(
        plunged(&r_low) <= plunged(&r_high) + 1e-6,
        "{name}: plunges remove {:.1} mm³ with links at depth, {:.1} without",
        plunged(&r_low),
        plunged(&r_high)
    );
    // a link: a level feed move at a lift height (a level's Z, or the stock top, plus the
    // lift); it removes nothing
    let hs = level_heights(&low);
    let lifts: Vec<f64> = hs
        .iter()
        .chain(std::iter::once(&top))
        .map(|h| h + LINK_LIFT)
        .filter(|l| hs.iter().any(|h| (h - l).abs() < 1e-9))
        .collect();
    let mut links = 0;
    for mv in &r_low.moves {
        let at_lift = level_at_any(mv, &lifts);
        if mv.kind == MoveKind::Cut && at_lift && mv.length > 1e-9 {
            links += 1;
            assert!(
                mv.removed == 0.0,
                "{name}: the link {:?} → {:?} cuts {} mm³",
                mv.from,
                mv.to,
                mv.removed
            );
        }
    }
    eprintln!("{name}: {links} links at depth, none removing material");
    assert!(links > 0, "{name}: no link at depth");
    // and the program with links keeps the allowance everywhere
    crate::rough3d::keeps_allowance(name, m, p, 0.02);
}

#[test]
fn a_cube_with_a_boss_retracts_less_and_links_through_air() {
    check(
        "cube 30 with a boss, margin 5",
        &cube_with_boss(30.0, 6.0, 8.0, 32),
        &params(5.0),
    );
}

#[test]
fn a_wavy_solid_retracts_less_and_links_through_air() {
    let m = height_field_solid((0.0, 40.0), (0.0, 30.0), 40, 30, 0.0, |x, y| {
        8.0 + 3.0 * (x / 6.0).sin() * (y / 5.0).cos()
    });
    check("wavy solid 40 × 30, margin 4", &m, &params(4.0));
}

#[test]
fn a_sphere_from_its_envelope_retracts_less_and_links_through_air() {
    let m = sphere(V3::new(0.0, 0.0, 10.0), 10.0, 16, 32);
    check("sphere r10 from its envelope, margin 4", &m, &params(4.0));
}
