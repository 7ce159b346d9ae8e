//! Profiles checked against the part by distance, not against the simulator: outside,
//! inside and on the line, with and without lead-ins and tabs, on parts with arcs and
//! islands. The tool centre never comes nearer the part than the tool radius R (and never
//! onto the part's side of the line), lies at R wherever it cuts the loop (lead arcs only
//! lie farther), and every point of the loop (the part's points moved R to the cutting side,
//! by the two-way checker's own rule, not the kernel's) is cut at every pass depth, except
//! under a tab, where it is cut down to the tab's top and no lower.

use offset_core::check::Checker;
use offset_core::geom::{Point, Polyline, Region, Segment, Shape, Vertex};
use offset_core::ops::{profile, Cutting, Entry, ProfileParams, Side};
use offset_core::toolpath::{arc_segment, Move, Tool, Toolpath, P3};

/// The plan's tolerance (arc fitting, offsets) and how near a cut must come to count.
const TOL: f64 = 1e-3;
const REACH: f64 = 4e-3;

/// A cutting move below the stock top, in plan and in height.
struct Cut {
    seg: Segment,
    z0: f64,
    z1: f64,
}

impl Cut {
    /// The plan distance from `p` and the height of the cut at the nearest point.
    fn reach(&self, p: Point) -> (f64, f64) {
        let q = self.seg.closest_point(p);
        let t = match self.seg {
            Segment::Line { a, b } => {
                let l2 = (b - a).dot(b - a);
                if l2 > 0.0 {
                    ((q - a).dot(b - a) / l2).clamp(0.0, 1.0)
                } else {
                    0.0
                }
            }
            Segment::Arc { a, center, ccw, .. } => {
                let full = self.seg.length();
                if full > 0.0 {
                    (arc_segment(a, q, center, ccw).length() / full).clamp(0.0, 1.0)
                } else {
                    0.0
                }
            }
        };
        (q.dist(p), self.z0 + (self.z1 - self.z0) * t)
    }
}

fn cuts(tp: &Toolpath) -> Vec<Cut> {
    let mut out = Vec::new();
    tp.walk(P3::default(), |from, m, to| {
        let seg = match m {
            Move::Linear { .. } => Segment::Line {
                a: from.xy(),
                b: to.xy(),
            },
            Move::Arc { center, ccw, .. } => arc_segment(from.xy(), to.xy(), *center, *ccw),
            _ => return,
        };
        if from.z < -1e-9 || to.z < -1e-9 {
            out.push(Cut {
                seg,
                z0: from.z,
                z1: to.z,
            });
        }
    });
    out
}

/// Whether `p` lies in the part (closed paths nested even-odd, as the importer reads them).
fn in_part(part: &[Polyline], p: Point) -> bool {
    part.iter().filter(|q| q.closed && q.contains(p)).count() % 2 == 1
}

struct Case {
    name: String,
    part: Vec<Polyline>,
    p: ProfileParams,
}

/// Checks one profile; returns how much of the loop was left at the tab height (mm of
/// expected loop per tab, roughly) so callers can check the tabs exist.
fn check_profile(c: &Case) -> f64 {
    let tp =
        profile(&Shape::new(c.part.clone()), &c.p).unwrap_or_else(|e| panic!("{}: {e}", c.name));
    check_plan(c, &tp)
}

/// Checks a plan against the case's part and parameters (see the file's paragraph).
fn check_plan(c: &Case, tp: &Toolpath) -> f64 {
    let name = &c.name;
    let r = c.p.cut.tool.radius();
    let cuts = cuts(tp);
    assert!(!cuts.is_empty(), "{name}: nothing cut");
    let part = Checker::new(&c.part);

    // 1. Nothing of the part touched: every point of every cut below the stock top lies on
    //    the cutting side and at least R from the part (On: on the line, or off it only on
    //    a lead arc).
    let mut on_loop = 0usize;
    for (i, cut) in cuts.iter().enumerate() {
        let k = ((cut.seg.length() / 0.05).ceil() as usize).clamp(2, 4000);
        for j in 0..=k {
            let q = cut.seg.point_at(j as f64 / k as f64);
            let d = part.distance(q);
            match c.p.side {
                Side::Outside | Side::Inside => {
                    assert!(
                        d >= r - TOL,
                        "{name}: cut {i} at {q:?} is {d} mm from the part, the tool radius is {r}"
                    );
                    let inside = in_part(&c.part, q);
                    assert_eq!(
                        inside,
                        c.p.side == Side::Inside,
                        "{name}: cut {i} at {q:?} is on the wrong side of the part's outline"
                    );
                    if d <= r + TOL {
                        on_loop += 1;
                    }
                }
                Side::On => {
                    if d <= TOL {
                        on_loop += 1;
                    }
                }
            }
        }
    }
    // 2. At R wherever it cuts: only lead-in and lead-out arcs may lie farther off the loop.
    let leads = c.p.lead_in > 0.0 || c.p.lead_out > 0.0;
    let samples: usize = cuts
        .iter()
        .map(|cut| ((cut.seg.length() / 0.05).ceil() as usize).clamp(2, 4000) + 1)
        .sum();
    if !leads {
        assert_eq!(
            on_loop,
            samples,
            "{name}: {} points of the cuts lie off the loop at R",
            samples - on_loop
        );
    } else {
        assert!(
            on_loop * 2 > samples,
            "{name}: only {on_loop} of {samples} cut points lie on the loop"
        );
    }

    // 3. The whole loop is cut at every pass depth (under tabs: down to the tab's top).
    let d = match c.p.side {
        Side::Outside => r,
        Side::Inside => -r,
        Side::On => 0.0,
    };
    let expected: Vec<Point> = if d == 0.0 {
        c.part
            .iter()
            .flat_map(|pl| {
                pl.segments()
                    .flat_map(|s| {
                        let k = ((s.length() / 0.1).ceil() as usize).max(1);
                        (0..k).map(move |j| s.point_at(j as f64 / k as f64))
                    })
                    .collect::<Vec<_>>()
            })
            .collect()
    } else {
        part.expected_points(d, 0.05)
            .into_iter()
            .map(|(p, _)| p)
            .collect()
    };
    assert!(
        expected.len() > 100,
        "{name}: {} points expected",
        expected.len()
    );
    // the pass depths worked out here, not by the planner's own function: equal steps of
    // at most the stepdown down to the depth
    let n = (c.p.cut.depth / c.p.cut.stepdown).ceil() as usize;
    let depths: Vec<f64> = (1..=n)
        .map(|k| -c.p.cut.depth * k as f64 / n as f64)
        .collect();
    let tab_z = -c.p.cut.depth + c.p.tab_height;
    let mut under_tab = 0usize;
    for e in &expected {
        let touched: Vec<f64> = cuts
            .iter()
            .filter_map(|cut| {
                let (dist, z) = cut.reach(*e);
                (dist <= REACH).then_some(z)
            })
            .collect();
        let lowest = touched.iter().cloned().fold(f64::INFINITY, f64::min);
        assert!(
            lowest.is_finite(),
            "{name}: the loop is never cut at {e:?} (it should pass {R} mm from the part)",
            R = d.abs()
        );
        assert!(
            lowest >= -c.p.cut.depth - 1e-6,
            "{name}: cut at {e:?} goes to {lowest}, below the depth {}",
            c.p.cut.depth
        );
        let tabbed = c.p.tabs > 0 && lowest > -c.p.cut.depth + 1e-6;
        if tabbed {
            under_tab += 1;
            assert!(
                lowest <= tab_z + 1e-6,
                "{name}: at {e:?} the cut stops at {lowest}, above the tab top {tab_z}"
            );
        }
        for &z in &depths {
            if tabbed && z < tab_z {
                continue;
            }
            assert!(
                touched.iter().any(|&t| (t - z).abs() <= 1e-6),
                "{name}: the pass at {z} misses {e:?} (cut there at {touched:?})"
            );
        }
    }
    // the tabs are there, about as wide as asked (the tool's diameter on top of the
    // material's width, plus the ramps back down), and nowhere else
    let spacing = expected_length(c, d) / expected.len() as f64;
    let tab_len = under_tab as f64 * spacing;
    if c.p.tabs == 0 {
        assert_eq!(under_tab, 0, "{name}");
    } else {
        let loops = loops_of(c);
        let least = (c.p.tabs * loops) as f64 * c.p.tab_width;
        assert!(
            tab_len >= least,
            "{name}: {tab_len} mm of the loops left at tabs, {least} mm asked for"
        );
    }
    tab_len
}

/// The length of the loop(s) the tool centre should follow.
fn expected_length(c: &Case, d: f64) -> f64 {
    if d == 0.0 {
        return c.part.iter().map(|p| p.length()).sum();
    }
    let regions = Shape::new(c.part.clone()).regions();
    regions
        .iter()
        .flat_map(|r| {
            offset_core::offset::offset_region(r, d, &Default::default())
                .unwrap()
                .into_iter()
                .flat_map(|o: Region| o.boundaries().map(|b| b.length()).collect::<Vec<_>>())
        })
        .sum()
}

fn loops_of(c: &Case) -> usize {
    Shape::new(c.part.clone())
        .regions()
        .iter()
        .map(|r| 1 + r.islands.len())
        .sum()
}

fn params(side: Side, lead: f64, tabs: usize) -> ProfileParams {
    ProfileParams {
        side,
        lead_in: lead,
        lead_out: lead,
        tabs,
        tab_width: 2.0,
        tab_height: 0.8,
        cut: Cutting {
            tool: Tool::flat(3.0),
            depth: 2.0,
            stepdown: 1.0,
            tolerance: TOL,
            ..Default::default()
        },
    }
}

/// A plate with rounded corners (arcs) and two round holes, one with a square boss in it.
fn plate() -> Vec<Polyline> {
    // 60 x 40 with corner radius 6: lines and quarter arcs (bulge tan(π/8))
    let b = (std::f64::consts::PI / 8.0).tan();
    let outer = Polyline::new(
        vec![
            Vertex::new(6.0, 0.0, 0.0),
            Vertex::new(54.0, 0.0, b),
            Vertex::new(60.0, 6.0, 0.0),
            Vertex::new(60.0, 34.0, b),
            Vertex::new(54.0, 40.0, 0.0),
            Vertex::new(6.0, 40.0, b),
            Vertex::new(0.0, 34.0, 0.0),
            Vertex::new(0.0, 6.0, b),
        ],
        true,
    );
    vec![
        outer,
        Polyline::circle(Point::new(18.0, 20.0), 8.0),
        Polyline::circle(Point::new(42.0, 20.0), 10.0),
        Polyline::rect(Point::new(40.0, 18.0), Point::new(44.0, 22.0)),
    ]
}

fn rect() -> Vec<Polyline> {
    vec![Polyline::rect(Point::new(0.0, 0.0), Point::new(40.0, 30.0))]
}

fn run(side: Side) {
    for (shape, part) in [("rectangle", rect()), ("plate with islands", plate())] {
        for lead in [0.0, 2.0] {
            for tabs in [0, 3] {
                for entry in [Entry::default(), Entry::Plunge] {
                    let mut p = params(side, lead, tabs);
                    p.cut.entry = entry;
                    check_profile(&Case {
                        name: format!(
                            "{side:?} profile of the {shape}, lead {lead}, {tabs} tabs, {entry:?}"
                        ),
                        part: part.clone(),
                        p,
                    });
                }
            }
        }
    }
}

#[test]
fn outside_profiles_keep_the_tool_centre_at_the_radius_outside_the_part() {
    run(Side::Outside);
}

#[test]
fn inside_profiles_keep_the_tool_centre_at_the_radius_inside_the_part() {
    run(Side::Inside);
}

#[test]
fn on_profiles_follow_the_line_at_every_depth() {
    run(Side::On);
}

#[test]
fn an_open_path_profile_follows_the_path_at_every_depth() {
    let wave = Polyline::new(
        vec![
            Vertex::new(0.0, 0.0, 0.3),
            Vertex::new(20.0, 0.0, -0.3),
            Vertex::new(40.0, 0.0, 0.0),
            Vertex::new(40.0, 20.0, 0.0),
        ],
        false,
    );
    for entry in [Entry::default(), Entry::Plunge] {
        let mut p = params(Side::On, 0.0, 0);
        p.cut.entry = entry;
        check_profile(&Case {
            name: format!("open wave, {entry:?}"),
            part: vec![wave.clone()],
            p,
        });
    }
}

#[test]
fn a_profile_cut_on_the_wrong_side_or_left_short_is_caught() {
    // the check itself: an inside profile passed off as an outside one, and an outside
    // profile with its last depth pass or half its loop dropped, each fail it
    let outside = params(Side::Outside, 0.0, 0);
    let inside_tp = profile(&Shape::new(rect()), &params(Side::Inside, 0.0, 0)).unwrap();
    let case = Case {
        name: "faulty".into(),
        part: rect(),
        p: outside.clone(),
    };
    let good = profile(&Shape::new(rect()), &outside).unwrap();
    check_plan(&case, &good);
    let mut shallow = good.clone();
    let depth = -outside.cut.depth;
    shallow.moves.iter_mut().for_each(|m| match m {
        Move::Linear { to, .. } | Move::Arc { to, .. } if (to.z - depth).abs() < 1e-9 => {
            to.z = depth + 1.0
        }
        _ => {}
    });
    let mut half = good.clone();
    let n = half.moves.len();
    half.moves.truncate(n / 2);
    for (what, tp) in [("inside", inside_tp), ("shallow", shallow), ("half", half)] {
        let r = std::panic::catch_unwind(|| check_plan(&case, &tp));
        assert!(r.is_err(), "the {what} plan passed as an outside profile");
    }
}
