//! Adaptive clearing, checked by the cutting simulation on what it planned: on the plate
//! with two islands, two rooms joined by a neck just wider than the tool, a 10,000-vertex
//! wavy region and a region of a shared DXF drawing, nothing the tool can reach is left
//! (the simulation's raster check, as the pocket tests use), nothing is gouged, no rapid
//! or plunge goes through material, and the bound holds on every level cut (the entries,
//! helices into each level's core, are printed apart) but going into a sharp corner of a
//! wall, where no path can hold it (the cutsim test
//! `going_into_a_sharp_corner_reads_its_turn_even_with_nothing_left_to_cut` shows why):
//! there the reading must stay within what the simulation reads with nothing to cut.
//! The machine time at the feed the bound allows is printed beside the contour-parallel
//! pocket's at the feed its worst corner allows (docs/BENCHMARKS.md).

use offset_core::cutsim::feed::chip_factor;
use offset_core::cutsim::{corner_reading, retracts, simulate, MoveKind, Part, SimOptions, Stock};
use offset_core::geom::{Point, Polyline, Shape, Vertex};
use offset_core::ops::{adaptive, pocket, AdaptiveParams, Cutting, PocketParams, Stepover};
use offset_core::stats::Kinematics;
use offset_core::toolpath::{Move, Tool, Toolpath, P3};

fn plate() -> Shape {
    Shape::new(vec![
        Polyline::rect(Point::new(0.0, 0.0), Point::new(120.0, 80.0)),
        Polyline::circle(Point::new(40.0, 40.0), 10.0),
        Polyline::rect(Point::new(75.0, 25.0), Point::new(95.0, 55.0)),
    ])
}

/// Two 30 × 30 rooms joined by a neck 6.4 mm wide (a 6 mm tool).
fn neck() -> Shape {
    Shape::new(vec![Polyline::from_points(
        &[
            Point::new(0.0, 0.0),
            Point::new(30.0, 0.0),
            Point::new(30.0, 11.8),
            Point::new(50.0, 11.8),
            Point::new(50.0, 0.0),
            Point::new(80.0, 0.0),
            Point::new(80.0, 30.0),
            Point::new(50.0, 30.0),
            Point::new(50.0, 18.2),
            Point::new(30.0, 18.2),
            Point::new(30.0, 30.0),
            Point::new(0.0, 30.0),
        ],
        true,
    )])
}

pub struct Outcome {
    pub tp: Toolpath,
    /// Every level cut (helices left out): its index, engagement, start and end.
    pub levels: Vec<(usize, f64, P3, P3)>,
    /// The largest engagement of a level cut (helices left out), and where.
    pub worst: f64,
    pub worst_at: (P3, usize),
}

/// Plans adaptive clearing of `shape` with a 6 mm tool and simulates it on a block over
/// the shape; asserts no gouge, nothing left, no rapid or plunge through material.
fn check(name: &str, shape: &Shape, depth: f64, bound: f64) -> Outcome {
    let p = AdaptiveParams {
        cut: Cutting {
            tool: Tool::flat(6.0),
            depth,
            stepdown: 1.0,
            feed: 800.0,
            ..Cutting::default()
        },
        engagement: bound,
        ..AdaptiveParams::default()
    };
    let t0 = std::time::Instant::now();
    let tp = adaptive(shape, &p).unwrap();
    let planned = t0.elapsed().as_secs_f64();
    if let Move::Comment { text } = &tp.moves[0] {
        eprintln!(
            "{name}: planned in {planned:.1} s: {text}; {:?}",
            tp.warnings
        );
    }
    let b = shape.bounds();
    let stock = Stock::block(
        b.min - Point::new(1.0, 1.0),
        b.max + Point::new(1.0, 1.0),
        0.0,
    );
    let o = SimOptions {
        cell: CELL,
        part: Some(Part {
            clear: shape.regions(),
            floor: -depth,
        }),
        ..SimOptions::new(Tool::flat(6.0))
    };
    let rep = simulate(&tp, &stock, &o).unwrap();
    let helix = helix_moves(&tp);
    let levels: Vec<_> = rep
        .moves
        .iter()
        .filter(|m| m.kind == MoveKind::Cut && !helix[m.index])
        .collect();
    let worst = levels
        .iter()
        .max_by(|a, b| a.engagement.total_cmp(&b.engagement));
    let cut = worst.map_or(0.0, |m| m.engagement);
    if std::env::var("ADAPTIVE_DEBUG").is_ok() {
        let mut v: Vec<_> = levels.iter().filter(|m| m.engagement > bound).collect();
        eprintln!("{name}: {} level moves over {bound}", v.len());
        for m in rep.moves.iter().filter(|m| m.gouges > 0).take(5) {
            eprintln!(
                "  gouge move {} {:?} -> {:?} {:?} prev {:?}",
                m.index,
                m.from,
                m.to,
                tp.moves[m.index],
                tp.moves[m.index - 1]
            );
        }
        v.sort_by(|a, b| b.engagement.total_cmp(&a.engagement));
        for m in v.iter().take(25) {
            eprintln!(
                "  move {} {:.1}° {:?} -> {:?} len {:.3} {:?}",
                m.index, m.engagement, m.from, m.to, m.length, tp.moves[m.index]
            );
        }
    }
    let entries: Vec<_> = rep.moves.iter().filter(|m| helix[m.index]).collect();
    let entry = entries.iter().map(|m| m.engagement).fold(0.0, f64::max);
    let entries = entries.len();
    eprintln!(
        "{name}: {} moves, worst cut {cut:.1}°, entries {entries} moves reading up to {entry:.0}°, {} retracts, {:.0} s at 800 mm/min, left {} cells, gouges {}",
        tp.moves.len(),
        retracts(&tp),
        rep.time(),
        rep.left,
        rep.gouges
    );
    assert_eq!(rep.gouges, 0, "{name}: gouge at {:?}", rep.first_gouge);
    assert_eq!(rep.rapid_cuts, 0, "{name}: rapid through material");
    assert_eq!(
        rep.left, 0,
        "{name}: {} mm² left at {:?}",
        rep.left_area, rep.first_left
    );
    // every plunge goes down through air
    for m in rep.moves.iter().filter(|m| m.kind == MoveKind::Plunge) {
        assert_eq!(
            m.removed, 0.0,
            "{name}: move {} plunges into material",
            m.index
        );
    }
    let worst_at = worst.map_or((P3::default(), 0), |m| (m.from, m.index));
    let levels = levels
        .iter()
        .map(|m| (m.index, m.engagement, m.from, m.to))
        .collect();
    Outcome {
        tp,
        levels,
        worst: cut,
        worst_at,
    }
}

/// The moves of the helices into the cores: a run of arcs about one centre that starts
/// going down (the last turn of each is flat, at the depth).
fn helix_moves(tp: &Toolpath) -> Vec<bool> {
    let mut out = vec![false; tp.moves.len()];
    let mut z = 0.0;
    let mut centre: Option<Point> = None;
    for (i, m) in tp.moves.iter().enumerate() {
        match m {
            Move::Arc { to, center, .. } => {
                if centre == Some(*center) || (centre.is_none() && to.z < z - 1e-9) {
                    centre = Some(*center);
                    out[i] = true;
                } else {
                    centre = None;
                }
                z = to.z;
            }
            Move::Linear { to, .. } | Move::Rapid { to } => {
                centre = None;
                z = to.z;
            }
            _ => {}
        }
    }
    out
}

/// The time of a tool path at the feed `feed` scaled by the chip thinning of its worst
/// level cut (the feed at which a tooth takes the chip a full slot takes at `feed`).
fn time_at_bound(tp: &Toolpath, worst: f64, feed: f64, max_feed: f64) -> (f64, f64) {
    let f = (feed / chip_factor(worst)).min(max_feed);
    let mut t = tp.clone();
    for m in &mut t.moves {
        if let Move::Linear { feed: g, .. } | Move::Arc { feed: g, .. } = m {
            if (*g - feed).abs() < 1e-9 {
                *g = f;
            }
        }
    }
    let k = Kinematics {
        max_feed,
        ..Kinematics::default()
    };
    (f, t.stats(&k).time())
}

#[test]
#[ignore = "a measurement (docs/BENCHMARKS.md, adaptive rows); run: cargo test -p offset-core --test it adaptive::the_plate_with -- --ignored --nocapture"]
fn the_plate_with_two_islands_is_cleared_without_a_gouge_and_measured_against_the_pocket() {
    let a = check("plate", &plate(), 2.0, 70.0);
    // the pocket at 40 %, simulated the same way, for the benchmark
    let shape = plate();
    let pp = PocketParams {
        cut: Cutting {
            tool: Tool::flat(6.0),
            depth: 2.0,
            stepdown: 1.0,
            feed: 800.0,
            ..Cutting::default()
        },
        stepover: Stepover::Percent(40.0),
    };
    let pk = pocket(&shape, &pp).unwrap();
    let stock = Stock::block(Point::new(-1.0, -1.0), Point::new(121.0, 81.0), 0.0);
    let o = SimOptions {
        cell: 0.1,
        ..SimOptions::new(Tool::flat(6.0))
    };
    let rp = simulate(&pk, &stock, &o).unwrap();
    let pw = rp.worst(&[MoveKind::Cut]).map_or(0.0, |m| m.engagement);
    let max_feed = 3000.0;
    let (fa, ta) = time_at_bound(&a.tp, a.worst, 800.0, max_feed);
    let (fp, tpk) = time_at_bound(&pk, pw, 800.0, max_feed);
    eprintln!(
        "benchmark plate: adaptive worst {:.1}° (at {:?}, move {}) → {fa:.0} mm/min, {ta:.0} s, {} retracts; pocket worst {pw:.1}° → {fp:.0} mm/min, {tpk:.0} s, {} retracts",
        a.worst,
        a.worst_at.0,
        a.worst_at.1,
        retracts(&a.tp),
        retracts(&pk)
    );
}

/// The sharp corners of the tool centre's path round the walls of `shape`, and their turns.
fn sharp_corners(shape: &Shape, r: f64) -> Vec<(Point, f64)> {
    offset_core::cutsim::sharp_corners(&shape.regions(), r)
}

/// The simulation's cell in these tests, mm.
const CELL: f64 = 0.1;

/// The level cuts that read more than `bound` where it can be held: away from the sharp
/// corners, more than `bound`; ending within `near` mm of one of `corners`, more than the
/// bound and more than the simulation reads going into that corner with nothing to cut
/// (`cutsim::corner_reading`: no plan reads less there). And the most
/// those near the corners read.
fn over_bound(
    a: &Outcome,
    bound: f64,
    corners: &[(Point, f64)],
    near: f64,
) -> (Vec<(usize, f64, P3)>, f64) {
    let mut over = Vec::new();
    let mut at_corners = 0.0f64;
    for &(i, e, from, to) in &a.levels {
        let corner = corners
            .iter()
            .filter(|(c, _)| c.dist(to.xy()) <= near)
            .map(|&(_, turn)| corner_reading(turn, 3.0, CELL))
            .fold(None, |m: Option<f64>, x| Some(m.map_or(x, |m| m.max(x))));
        if let Some(least) = corner {
            at_corners = at_corners.max(e);
            if e > bound.max(least) {
                over.push((i, e, from));
            }
        } else if e > bound {
            over.push((i, e, from));
        }
    }
    (over, at_corners)
}

/// The bound on every level cut of the plate, checked by the simulation; going into the
/// four sharp corners of the outer wall (the last 0.5 mm before each), where no plan can
/// hold it, nothing more than the simulation reads there with nothing to cut (90° and
/// the wall ahead).
#[test]
fn the_plate_keeps_the_engagement_bound() {
    let a = check("plate", &plate(), 2.0, 70.0);
    // one helix into the one core, boring it for both levels: the second goes down the
    // bored core through air (`check` asserts every plunge removes nothing)
    let helix = helix_moves(&a.tp);
    let helices = helix.windows(2).filter(|w| !w[0] && w[1]).count();
    assert_eq!(helices, 1, "{helices} helices for one core and two levels");
    let corners = sharp_corners(&plate(), 3.0);
    assert_eq!(corners.len(), 4, "{corners:?}");
    let (over, at_corners) = over_bound(&a, 70.0, &corners, 0.5);
    eprintln!(
        "plate: worst going into the sharp corners {at_corners:.1}° (with nothing left to cut up to {:.1}°)",
        corner_reading(90.0, 3.0, CELL)
    );
    assert!(
        over.is_empty(),
        "{} level cuts over the bound, the worst {:?}",
        over.len(),
        over.iter().max_by(|x, y| x.1.total_cmp(&y.1))
    );
}

/// The bound through a neck 0.4 mm wider than the tool (trochoidal loops of 0.18 mm along
/// it), and everywhere else but going into the eight sharp corners of the rooms' walls.
#[test]
fn a_neck_just_wider_than_the_tool_keeps_the_engagement_bound() {
    let a = check("neck", &neck(), 1.0, 70.0);
    let corners = sharp_corners(&neck(), 3.0);
    assert_eq!(corners.len(), 8, "{corners:?}");
    let (over, at_corners) = over_bound(&a, 70.0, &corners, 0.5);
    // the neck itself: the cuts whose ends lie in it
    let in_neck = a
        .levels
        .iter()
        .filter(|l| (30.0..=50.0).contains(&l.3.x) && (11.8..=18.2).contains(&l.3.y))
        .map(|l| l.1)
        .fold(0.0, f64::max);
    eprintln!(
        "neck: worst in the neck {in_neck:.1}°, going into the sharp corners {at_corners:.1}°"
    );
    assert!(in_neck > 20.0, "the neck is not cut at depth ({in_neck}°)");
    assert!(
        over.is_empty(),
        "{} level cuts over the bound, the worst {:?}",
        over.len(),
        over.iter().max_by(|x, y| x.1.total_cmp(&y.1))
    );
}

/// An outline of 10,000 vertices, wavy (a circle of 28 mm with 10 waves of 1 mm), with a
/// round island and a wavy one.
fn wavy() -> Shape {
    let ring = |c: Point, r0: f64, amp: f64, waves: f64, n: usize, ccw: bool| {
        let pts: Vec<Point> = (0..n)
            .map(|i| {
                let t = i as f64 / n as f64 * std::f64::consts::TAU;
                let t = if ccw { t } else { -t };
                let r = r0 + amp * (waves * t).sin();
                c + Point::new(r * t.cos(), r * t.sin())
            })
            .collect();
        Polyline::from_points(&pts, true)
    };
    Shape::new(vec![
        ring(Point::new(30.0, 30.0), 28.0, 1.0, 10.0, 10_000, true),
        ring(Point::new(18.0, 30.0), 4.0, 0.0, 0.0, 400, false),
        ring(Point::new(42.0, 32.0), 5.0, 0.4, 7.0, 600, false),
    ])
}

#[test]
fn a_wavy_region_of_10000_vertices_with_islands_keeps_the_engagement_bound() {
    let shape = wavy();
    assert!(shape.paths[0].len() == 10_000);
    let a = check("wavy", &shape, 1.0, 70.0);
    let corners = sharp_corners(&shape, 3.0);
    let (away, at_corners) = over_bound(&a, 70.0, &corners, 0.5);
    eprintln!(
        "wavy: {} sharp wall corners, worst near them {at_corners:.1}°",
        corners.len()
    );
    assert!(
        away.is_empty(),
        "{} level cuts over 70°, the worst {:?}",
        away.len(),
        away.iter().max_by(|x, y| x.1.total_cmp(&y.1))
    );
}

/// shared/data/dxf/1_polylines.dxf, its closed outline of 19 vertices (its numbers read as
/// µm, so scaled by 1/1000 into mm: 59 × 67 mm; the outline with two islands has an
/// island that crosses itself, which the offset refuses).
fn dxf_region() -> Shape {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data/dxf/1_polylines.dxf");
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let (shape, _) = offset_core::io::read_shape_with(
        &bytes,
        "1_polylines.dxf",
        &offset_core::io::ReadOptions {
            layers: Vec::new(),
            colors: Vec::new(),
            tolerance: 0.01,
        },
    )
    .unwrap();
    let region = shape
        .regions()
        .into_iter()
        .find(|r| r.boundaries().map(|b| b.len()).sum::<usize>() == 19)
        .expect("the outline of 19 vertices");
    let o = region.bounds().min;
    Shape::new(
        region
            .boundaries()
            .map(|pl| {
                // a bulge is the same at any scale
                let vs = pl
                    .vertices
                    .iter()
                    .map(|v| {
                        let p = (v.pos() - o) * 0.001;
                        Vertex::new(p.x, p.y, v.bulge)
                    })
                    .collect();
                Polyline::new(vs, true)
            })
            .collect(),
    )
}

#[test]
fn a_region_of_a_shared_dxf_drawing_keeps_the_engagement_bound() {
    let shape = dxf_region();
    let a = check("dxf", &shape, 1.0, 70.0);
    let corners = sharp_corners(&shape, 3.0);
    let (over, at_corners) = over_bound(&a, 70.0, &corners, 0.5);
    eprintln!(
        "dxf: sharp wall corners turning {:?}°, worst near them {at_corners:.1}°",
        corners.iter().map(|c| c.1.round()).collect::<Vec<_>>()
    );
    assert!(
        over.is_empty(),
        "{} level cuts over the bound, the worst {:?}",
        over.len(),
        over.iter().max_by(|x, y| x.1.total_cmp(&y.1))
    );
}

#[test]
fn the_same_shape_plans_the_same_program_twice() {
    let shape = Shape::new(vec![
        Polyline::rect(Point::new(0.0, 0.0), Point::new(30.0, 20.0)),
        Polyline::circle(Point::new(11.5, 10.0), 2.5),
    ]);
    let p = AdaptiveParams {
        cut: Cutting {
            tool: Tool::flat(6.0),
            depth: 1.0,
            ..Cutting::default()
        },
        ..AdaptiveParams::default()
    };
    let a = adaptive(&shape, &p).unwrap();
    let b = adaptive(&shape, &p).unwrap();
    assert!(a.moves.len() > 100, "{} moves", a.moves.len());
    assert_eq!(a.moves, b.moves, "two plans of one shape differ");
}
