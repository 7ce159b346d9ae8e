//! Cutting simulation against closed forms: a slot of the tool's width reads 180°, a
//! straight cut at step-over s reads arccos(1 − 2s/D), arcs round a boss and round a bore
//! read the outside and inside corner formulas; the material a pocket leaves agrees with
//! the raster coverage check of the pocket tests; gouges, rapids through material and air
//! cuts are found where they are.

use crate::pocket_support;

use offset_core::cutsim::{corner_reading, simulate, MoveKind, Part, Report, SimOptions, Stock};
use offset_core::geom::{Point, Polyline, Region, Shape};
use offset_core::ops::{pocket, Cutting, PocketParams, Stepover};
use offset_core::toolpath::{Move, Tool, Toolpath, P3};
use pocket_support::check_coverage;

const D: f64 = 6.0;
const R: f64 = 3.0;
const CELL: f64 = 0.05;
/// The raster reads the contact just outside the tool (R + 0.72 cell, up to 1.4° high at
/// small engagement), the material's edge to half a cell (up to 0.9° at small engagement)
/// and the angle in 1° probes: within 2.5° at a 120th of the diameter.
const TOL: f64 = 2.5;

fn opts() -> SimOptions {
    SimOptions {
        cell: CELL,
        ..SimOptions::new(Tool::flat(D))
    }
}

fn rapid(x: f64, y: f64, z: f64) -> Move {
    Move::Rapid {
        to: P3::new(x, y, z),
    }
}
fn line(x: f64, y: f64, z: f64) -> Move {
    Move::Linear {
        to: P3::new(x, y, z),
        feed: 600.0,
    }
}

fn path(moves: Vec<Move>) -> Toolpath {
    let mut tp = Toolpath::new("test");
    tp.tool = Some(Tool::flat(D));
    tp.moves = moves;
    tp
}

/// The engagement of the samples of report move `m` whose x (or angle) lies in `keep`.
fn steady(rep: &Report, m: usize, keep: impl Fn(P3) -> bool) -> Vec<f64> {
    rep.samples
        .iter()
        .filter(|s| s.report == m && keep(s.at))
        .map(|s| s.engagement)
        .collect()
}

fn assert_near(name: &str, got: &[f64], want: f64, tol: f64) {
    assert!(got.len() > 20, "{name}: only {} samples", got.len());
    for &g in got {
        assert!(
            (g - want).abs() <= tol,
            "{name}: read {g:.2}°, the closed form gives {want:.2}° (±{tol}°)"
        );
    }
}

fn block() -> Stock {
    Stock::block(Point::new(0.0, -20.0), Point::new(100.0, 20.0), 0.0)
}

#[test]
fn a_slot_of_the_tool_width_reads_180_degrees() {
    let tp = path(vec![
        rapid(-10.0, 0.0, 5.0),
        line(-10.0, 0.0, -1.0),
        line(90.0, 0.0, -1.0),
    ]);
    let rep = simulate(&tp, &block(), &opts()).unwrap();
    let cut = rep
        .moves
        .iter()
        .position(|m| m.kind == MoveKind::Cut)
        .unwrap();
    assert_near(
        "slot",
        &steady(&rep, cut, |p| p.x > 10.0 && p.x < 85.0),
        180.0,
        0.01,
    );
    // the tool starts in air: a stretch of the cut before it meets the stock's edge
    let air = rep.moves[cut].air;
    assert!(
        (air - (10.0 - R)).abs() < 2.0 * CELL,
        "air {air}, report {:?}",
        rep.moves[cut]
    );
    // the slot removed its volume: width D over 90 mm, 1 mm deep, plus the round end
    let want = D * 90.0 + std::f64::consts::PI * R * R / 2.0;
    assert!(
        (rep.removed - want).abs() / want < 0.01,
        "{} vs {want}",
        rep.removed
    );
}

#[test]
fn a_straight_cut_at_step_over_s_reads_arccos_1_minus_2s_over_d() {
    for s in [0.3, 1.2, 2.4, 3.0, 4.5, 5.4] {
        let tp = path(vec![
            rapid(-10.0, 0.0, 5.0),
            line(-10.0, 0.0, -1.0),
            line(95.0, 0.0, -1.0),
            line(95.0, s, -1.0),
            line(-10.0, s, -1.0),
        ]);
        let rep = simulate(&tp, &block(), &opts()).unwrap();
        let want = (1.0 - 2.0 * s / D).acos().to_degrees();
        let back = rep.moves.len() - 1;
        // the raster reads the cut edge within about a cell: a degree or so
        let got = steady(&rep, back, |p| p.x > 10.0 && p.x < 85.0);
        assert_near(&format!("step-over {s} mm"), &got, want, TOL);
    }
}

/// A full circle of the tool centre at radius `rho` about the origin, from (rho, 0).
fn circle_path(rho: f64) -> Toolpath {
    path(vec![
        rapid(rho, 0.0, 5.0),
        line(rho, 0.0, -1.0),
        Move::Arc {
            to: P3::new(-rho, 0.0, -1.0),
            center: Point::default(),
            ccw: true,
            feed: 600.0,
        },
        Move::Arc {
            to: P3::new(rho, 0.0, -1.0),
            center: Point::default(),
            ccw: true,
            feed: 600.0,
        },
    ])
}

/// Samples of the first lap between 30° and 250° (clear of the disc the plunge cut).
fn lap(rep: &Report) -> Vec<f64> {
    let arcs: Vec<usize> = (0..rep.moves.len())
        .filter(|&m| rep.moves[m].kind == MoveKind::Cut)
        .collect();
    rep.samples
        .iter()
        .filter(|s| arcs.contains(&s.report))
        .filter(|s| {
            let a = s.at.y.atan2(s.at.x).to_degrees().rem_euclid(360.0);
            a > 30.0 && a < 250.0
        })
        .map(|s| s.engagement)
        .collect()
}

#[test]
fn an_arc_round_a_boss_reads_the_outside_corner_formula() {
    for (rho, ae) in [(10.0, 1.2), (6.0, 2.0), (20.0, 0.6)] {
        // material inside radius rho - R + ae: the tool takes ae off a boss
        let rm = rho - R + ae;
        let stock = Stock {
            outline: vec![Region::new(Polyline::circle(Point::default(), rm), vec![])],
            top: 0.0,
        };
        let rep = simulate(&circle_path(rho), &stock, &opts()).unwrap();
        let want = ((rho * rho + R * R - rm * rm) / (2.0 * rho * R))
            .acos()
            .to_degrees();
        assert_near(&format!("boss rho {rho} ae {ae}"), &lap(&rep), want, TOL);
    }
}

#[test]
fn an_arc_round_a_bore_reads_the_inside_corner_formula() {
    for (rho, ae) in [(10.0, 1.2), (6.0, 2.0), (20.0, 0.6)] {
        // material outside radius rho + R - ae: the tool opens a bore by ae
        let rm = rho + R - ae;
        let stock = Stock {
            outline: vec![Region::new(
                Polyline::rect(Point::new(-40.0, -40.0), Point::new(40.0, 40.0)),
                vec![Polyline::circle(Point::default(), rm)],
            )],
            top: 0.0,
        };
        let rep = simulate(&circle_path(rho), &stock, &opts()).unwrap();
        let want = ((rm * rm - rho * rho - R * R) / (2.0 * rho * R))
            .acos()
            .to_degrees();
        assert_near(&format!("bore rho {rho} ae {ae}"), &lap(&rep), want, TOL);
    }
}

fn plate() -> Shape {
    Shape::new(vec![
        Polyline::rect(Point::new(0.0, 0.0), Point::new(60.0, 40.0)),
        Polyline::circle(Point::new(20.0, 20.0), 6.0),
        Polyline::rect(Point::new(36.0, 12.0), Point::new(46.0, 28.0)),
    ])
}

fn pocket_params() -> PocketParams {
    PocketParams {
        cut: Cutting {
            tool: Tool::flat(D),
            depth: 2.0,
            stepdown: 1.0,
            ..Cutting::default()
        },
        stepover: Stepover::Percent(40.0),
    }
}

fn stock_over(shape: &Shape) -> Stock {
    let b = shape.bounds();
    Stock::block(b.min, b.max, 0.0)
}

#[test]
fn the_material_a_pocket_leaves_agrees_with_the_coverage_check() {
    let shape = plate();
    let region = shape.regions()[0].clone();
    let full = pocket(&shape, &pocket_params()).unwrap();
    let o = SimOptions {
        cell: 0.1,
        part: Some(Part {
            clear: vec![region.clone()],
            floor: -2.0,
        }),
        ..opts()
    };
    let rep = simulate(&full, &stock_over(&shape), &o).unwrap();
    let cov = check_coverage(&region, &full, R, -2.0, 0.1, 0.01);
    assert_eq!((cov.uncut, cov.gouges), (0, 0));
    assert_eq!(
        rep.left, 0,
        "the whole pocket leaves material at {:?}",
        rep.first_left
    );
    assert_eq!(rep.gouges, 0, "gouge at {:?}", rep.first_gouge);
    assert_eq!(rep.rapid_cuts, 0);
    // the pocket's volume: its area (less what a round tool cannot reach) 2 mm deep
    let area = region.area();
    assert!(
        rep.removed < area * 2.0 && rep.removed > area * 2.0 * 0.97,
        "{} of {}",
        rep.removed,
        area * 2.0
    );
    // the same pocket stopped two thirds of the way through: both find the same area left
    for keep in [0.67, 0.85] {
        let mut part = full.clone();
        part.moves
            .truncate((full.moves.len() as f64 * keep) as usize);
        let rep = simulate(&part, &stock_over(&shape), &o).unwrap();
        let cov = check_coverage(&region, &part, R, -2.0, 0.1, 0.01);
        let (a, b) = (rep.left as f64, cov.uncut as f64);
        assert!(
            b > 500.0,
            "the cut-short pocket leaves material ({b} cells)"
        );
        assert!(
            (a - b).abs() / b < 0.02,
            "cut at {keep}: the simulation leaves {a} cells, the coverage check {b}"
        );
    }
}

#[test]
fn gouges_rapids_through_material_and_air_cuts_are_found_where_they_are() {
    let shape = plate();
    let region = shape.regions()[0].clone();
    let o = SimOptions {
        part: Some(Part {
            clear: vec![region],
            floor: -2.0,
        }),
        ..opts()
    };
    // a cut along y = 10 that runs into the round island (centre 20,20 r 6) at x 20,
    // then too deep, then a rapid back through the material, then a cut in air
    let tp = path(vec![
        rapid(5.0, 10.0, 5.0),
        line(5.0, 10.0, -1.0),
        line(20.0, 16.0, -1.0),
        line(20.0, 10.0, -1.0),
        line(30.0, 10.0, -3.0),
        rapid(5.0, 30.0, -0.5),
        line(5.0, 30.0, 5.0),
        line(50.0, 30.0, 5.0),
    ]);
    let rep = simulate(&tp, &stock_over(&shape), &o).unwrap();
    let by_index = |i: usize| rep.moves.iter().find(|m| m.index == i).unwrap();
    assert!(by_index(2).gouges > 0, "the cut into the island gouges");
    let g = rep.first_gouge.unwrap();
    assert!(
        g.dist(Point::new(20.0, 20.0)) < 6.0,
        "first gouge at {g:?}, inside the island"
    );
    assert!(
        by_index(4).gouges > 0,
        "the ramp below the floor cuts deeper than planned"
    );
    assert_eq!(
        rep.rapid_cuts, 1,
        "the rapid at Z -0.5 goes through material"
    );
    assert_eq!(rep.first_rapid_cut, Some(5));
    let air = rep.longest_air().unwrap();
    assert!((air.length - 50.5).abs() < 0.2, "longest air cut {air:?}");
    assert_eq!(by_index(7).engagement, 0.0);
}

/// Why no plan holds an engagement bound going into a sharp corner of a region: where the
/// tool centre's path (the region offset inward by R) turns by τ on the spot, at C, the
/// material only the tool at C reaches lies round its edge over the directions of the
/// corner's normal cone, τ = 180° less the corner's angle. Whatever way the tool comes in,
/// those directions face its way, so its edge meets material (or the part just beyond)
/// over at least τ as it arrives. The simulation reads the same: the pocket is cut, then
/// the wall loop is run once more through air, and each arrival at a corner reads at least
/// τ though it removes nothing; and at most `corner_reading`, τ and the wall ahead that
/// the probes just outside the tool touch, which shrinks with the cell. The adaptive tests
/// hold corners to that.
#[test]
fn going_into_a_sharp_corner_reads_its_turn_even_with_nothing_left_to_cut() {
    let p = Point::new;
    let shapes = [
        (
            "rectangle",
            vec![p(0.0, 0.0), p(40.0, 0.0), p(40.0, 30.0), p(0.0, 30.0)],
        ),
        ("triangle", vec![p(0.0, 0.0), p(50.0, 0.0), p(10.0, 30.0)]),
    ];
    for (name, pts) in shapes {
        let shape = Shape::new(vec![Polyline::from_points(&pts, true)]);
        let region = shape.regions()[0].clone();
        let mut tp = pocket(&shape, &pocket_params()).unwrap();
        let wall = offset_core::offset::offset_region(&region, -R, &Default::default()).unwrap();
        let loop_pts: Vec<Point> = wall[0].outer.vertices.iter().map(|v| v.pos()).collect();
        assert_eq!(
            loop_pts.len(),
            pts.len(),
            "{name}: the wall path {loop_pts:?}"
        );
        let first = tp.moves.len();
        tp.moves.push(rapid(loop_pts[0].x, loop_pts[0].y, 5.0));
        tp.moves.push(line(loop_pts[0].x, loop_pts[0].y, -2.0));
        for q in loop_pts.iter().skip(1).chain(std::iter::once(&loop_pts[0])) {
            tp.moves.push(line(q.x, q.y, -2.0));
        }
        // the part stands round the region, as in a real block
        let b = shape.bounds();
        let block = Stock::block(b.min - p(1.0, 1.0), b.max + p(1.0, 1.0), 0.0);
        for cell in [0.1, 0.05, 0.025] {
            let o = SimOptions {
                cell,
                part: Some(Part {
                    clear: vec![region.clone()],
                    floor: -2.0,
                }),
                ..opts()
            };
            let rep = simulate(&tp, &block, &o).unwrap();
            assert_eq!(
                rep.left, 0,
                "{name}: the pocket leaves material at {:?}",
                rep.first_left
            );
            let n = loop_pts.len();
            for k in 0..n {
                // the move of the last loop that arrives at corner k + 1
                let (a, c, b) = (loop_pts[k], loop_pts[(k + 1) % n], loop_pts[(k + 2) % n]);
                let turn = (c - a)
                    .unit()
                    .dot((b - c).unit())
                    .clamp(-1.0, 1.0)
                    .acos()
                    .to_degrees();
                let m = rep
                    .moves
                    .iter()
                    .find(|m| m.index == first + 2 + k)
                    .expect("the move's report");
                assert!(
                    m.to.xy().dist(c) < 1e-9,
                    "{name}: move {} ends at {:?}",
                    m.index,
                    m.to
                );
                assert!(
                    m.removed < 1e-9,
                    "{name}: the loop through air removes {} mm³ going into {c:?}",
                    m.removed
                );
                let most = corner_reading(turn, R, cell);
                assert!(
                    m.engagement >= turn && m.engagement <= most,
                    "{name}, {cell} mm cells: going into {c:?} (a turn of {turn:.1}°) reads {:.1}°, not from {turn:.1}° to {most:.1}°",
                    m.engagement
                );
            }
        }
    }
}
