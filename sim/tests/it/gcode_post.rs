//! The G-code post, read back by the simulated GRBL's own interpreter: every line is one
//! GRBL accepts (arcs pass its error:33 check), and the path it describes is the planned one.

use machlink_protocols::gcode::{post, Dialect, GcodeOptions};
use machlink_protocols::grbl::{GrblLink, GrblOptions};
use machlink_protocols::{Control, Link, StreamEnd};
use machlink_sim::grbl::interp::{clean_line, Action, Interpreter, Motion};
use machlink_sim::grbl::{max_deviation, Executed, GrblSim, GrblSimConfig};
use offset_core::{Move, Point, Toolpath, P3};
use proptest::prelude::*;
use tokio::sync::{mpsc, watch};

fn lines(p: &[String]) -> &[String] {
    p
}

/// Reads G-code as GRBL would; Err names the line and GRBL's error code.
fn read_back(gcode: &[String]) -> Result<Vec<Executed>, String> {
    let mut interp = Interpreter::new();
    let mut out = Vec::new();
    for (i, l) in gcode.iter().enumerate() {
        let acts = interp
            .execute(&clean_line(l))
            .map_err(|code| format!("line {} {l:?}: error:{code}", i + 1))?;
        for a in acts {
            if let Action::Move {
                motion,
                from,
                to,
                center,
                feed,
            } = a
            {
                out.push(Executed {
                    index: i as u64 + 1,
                    line: l.clone(),
                    motion,
                    from,
                    to,
                    center,
                    feed,
                });
            }
        }
    }
    Ok(out)
}

/// The planned path as the moves a machine following it exactly would make.
fn as_executed(tp: &Toolpath) -> Vec<Executed> {
    let mut out = Vec::new();
    tp.walk(P3::default(), |from, m, to| {
        let (motion, center, feed) = match m {
            Move::Rapid { .. } => (Motion::Rapid, None, 0.0),
            Move::Linear { feed, .. } => (Motion::Linear, None, *feed),
            Move::Arc {
                center, ccw, feed, ..
            } => (
                if *ccw { Motion::ArcCcw } else { Motion::ArcCw },
                Some([center.x, center.y]),
                *feed,
            ),
            _ => return,
        };
        out.push(Executed {
            index: out.len() as u64 + 1,
            line: String::new(),
            motion,
            from: [from.x, from.y, from.z],
            to: [to.x, to.y, to.z],
            center,
            feed,
        });
    });
    out
}

/// The executed moves as a tool path.
fn as_toolpath(ex: &[Executed]) -> Toolpath {
    let mut tp = Toolpath::new("read back");
    let p = |a: [f64; 3]| P3::new(a[0], a[1], a[2]);
    if let Some(first) = ex.first() {
        tp.push(Move::Rapid { to: p(first.from) });
    }
    for e in ex {
        tp.push(match (e.motion, e.center) {
            (Motion::Rapid, _) => Move::Rapid { to: p(e.to) },
            (Motion::ArcCw | Motion::ArcCcw, Some(c)) => Move::Arc {
                to: p(e.to),
                center: Point::new(c[0], c[1]),
                ccw: e.motion == Motion::ArcCcw,
                feed: e.feed,
            },
            _ => Move::Linear {
                to: p(e.to),
                feed: e.feed,
            },
        });
    }
    tp
}

#[derive(Clone, Debug)]
enum Step {
    Line {
        dx: f64,
        dy: f64,
        dz: f64,
        feed: f64,
    },
    Arc {
        r: f64,
        phase: f64,
        sweep: f64,
        dz: f64,
        feed: f64,
    },
    FullCircle {
        r: f64,
        phase: f64,
        ccw: bool,
        feed: f64,
    },
    Rapid {
        x: f64,
        y: f64,
    },
}

fn step() -> impl Strategy<Value = Step> {
    prop_oneof![
        (
            -80.0..80.0f64,
            -80.0..80.0f64,
            -2.0..2.0f64,
            10.0..3000.0f64
        )
            .prop_map(|(dx, dy, dz, feed)| Step::Line { dx, dy, dz, feed }),
        (
            0.05..100.0f64,
            0.0..6.3f64,
            prop_oneof![-6.2..-0.02f64, 0.02..6.2f64],
            prop_oneof![Just(0.0), -3.0..3.0f64],
            10.0..3000.0f64
        )
            .prop_map(|(r, phase, sweep, dz, feed)| Step::Arc {
                r,
                phase,
                sweep,
                dz,
                feed
            }),
        (0.5..100.0f64, 0.0..6.3f64, any::<bool>(), 10.0..3000.0f64).prop_map(
            |(r, phase, ccw, feed)| Step::FullCircle {
                r,
                phase,
                ccw,
                feed
            }
        ),
        (-300.0..300.0f64, -300.0..300.0f64).prop_map(|(x, y)| Step::Rapid { x, y }),
    ]
}

fn build(start: (f64, f64), steps: &[Step]) -> Toolpath {
    let mut tp = Toolpath::new("property");
    let mut pos = P3::new(start.0, start.1, 5.0);
    tp.push(Move::Rapid { to: pos });
    pos.z = -1.0;
    tp.push(Move::Linear {
        to: pos,
        feed: 300.0,
    });
    for s in steps {
        match *s {
            Step::Line { dx, dy, dz, feed } => {
                pos = P3::new(pos.x + dx, pos.y + dy, pos.z + dz);
                tp.push(Move::Linear { to: pos, feed });
            }
            Step::Arc {
                r,
                phase,
                sweep,
                dz,
                feed,
            } => {
                let c = Point::new(pos.x - r * phase.cos(), pos.y - r * phase.sin());
                let end = c + Point::new((phase + sweep).cos(), (phase + sweep).sin()) * r;
                pos = P3::new(end.x, end.y, pos.z + dz);
                tp.push(Move::Arc {
                    to: pos,
                    center: c,
                    ccw: sweep > 0.0,
                    feed,
                });
            }
            Step::FullCircle {
                r,
                phase,
                ccw,
                feed,
            } => {
                let c = Point::new(pos.x - r * phase.cos(), pos.y - r * phase.sin());
                tp.push(Move::Arc {
                    to: pos,
                    center: c,
                    ccw,
                    feed,
                });
            }
            Step::Rapid { x, y } => {
                pos = P3::new(x, y, 5.0);
                tp.push(Move::Rapid { to: pos });
                pos.z = -1.0;
                tp.push(Move::Linear {
                    to: pos,
                    feed: 300.0,
                });
            }
        }
    }
    tp
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(offset_core::check::proptest_cases(32)))]

    #[test]
    fn grbl_posts_are_short_ascii_accepted_and_reproduce_the_path(
        start in (-200.0..200.0f64, -200.0..200.0f64),
        steps in prop::collection::vec(step(), 1..16),
    ) {
        let tp = build(start, &steps);
        let program = post(&tp, &GcodeOptions::default()).unwrap();
        let gcode = lines(&program);
        for l in gcode {
            prop_assert!(l.len() <= 80, "{l:?} is {} characters", l.len());
            prop_assert!(l.bytes().all(|b| (b' '..0x7f).contains(&b)), "{l:?}");
            prop_assert!(!l.contains("-0.000 ") && !l.ends_with("-0.000"), "{l:?}");
            prop_assert!(!l.contains(['e', 'E', '(', ';']), "{l:?}");
        }
        // GRBL's own rules, arc check included, accept every line
        let executed = read_back(gcode).map_err(TestCaseError::fail)?;
        // every move ends within 0.001 mm of its planned end (rounding to 3 decimals moves
        // a point by at most 0.00087 mm) ...
        let planned = as_executed(&tp);
        let moves: Vec<&Executed> = executed.iter().skip(1).collect(); // after the safe-Z rapid
        for (k, p) in planned.iter().enumerate() {
            // lines of zero length are not written; find the move that ends there
            let hit = moves.iter().any(|e| {
                let d = ((e.to[0] - p.to[0]).powi(2) + (e.to[1] - p.to[1]).powi(2) + (e.to[2] - p.to[2]).powi(2)).sqrt();
                d <= 1e-3
            });
            prop_assert!(hit, "no move ends within 0.001 mm of planned move {k}'s end {:?}", p.to);
        }
        // ... and the whole path, arcs sampled, stays within 0.0015 mm both ways: an arc
        // pinned to rounded ends with a centre on the 0.001 mm grid cannot always do better
        let there = max_deviation(&tp, &executed);
        prop_assert!(there <= 1.5e-3, "the G-code strays {there} mm from the plan");
        let back = max_deviation(&as_toolpath(&executed), &planned);
        prop_assert!(back <= 1.5e-3, "the plan strays {back} mm from the G-code");
    }

    #[test]
    fn arcs_whose_ends_are_off_the_circle_still_pass_grbls_check(
        r in 0.05..20.0f64,
        phase in 0.0..6.3f64,
        sweep in prop_oneof![-6.0..-0.1f64, 0.1..6.0f64],
        noise in (-0.02..0.02f64, -0.02..0.02f64),
    ) {
        let c = Point::new(10.0, 10.0);
        let a = c + Point::new(phase.cos(), phase.sin()) * r;
        let b = c + Point::new((phase + sweep).cos(), (phase + sweep).sin()) * r;
        let mut tp = Toolpath::new("noisy arc");
        tp.push(Move::Rapid { to: P3::new(a.x, a.y, 0.0) });
        tp.push(Move::Arc {
            to: P3::new(b.x + noise.0, b.y + noise.1, 0.0),
            center: c,
            ccw: sweep > 0.0,
            feed: 500.0,
        });
        let program = post(&tp, &GcodeOptions::default()).unwrap();
        read_back(lines(&program)).map_err(TestCaseError::fail)?;
    }
}

#[test]
fn linuxcnc_and_generic_posts_read_back_the_same_path() {
    let steps = vec![
        Step::Arc {
            r: 10.0,
            phase: 0.3,
            sweep: 4.0,
            dz: -1.0,
            feed: 600.0,
        },
        Step::Line {
            dx: 5.0,
            dy: -3.0,
            dz: 0.0,
            feed: 800.0,
        },
        Step::FullCircle {
            r: 4.0,
            phase: 1.0,
            ccw: false,
            feed: 800.0,
        },
    ];
    let tp = build((0.0, 0.0), &steps);
    for dialect in [Dialect::Linuxcnc, Dialect::Generic] {
        let program = post(
            &tp,
            &GcodeOptions {
                dialect,
                ..Default::default()
            },
        )
        .unwrap();
        // the LinuxCNC tool change is not GRBL's; read the rest
        let gcode: Vec<String> = lines(&program)
            .iter()
            .filter(|l| !l.contains("M6") && !l.contains("G40"))
            .cloned()
            .collect();
        let executed = read_back(&gcode).unwrap();
        assert!(max_deviation(&tp, &executed) <= 1.5e-3);
    }
}

/// A part with arcs and helices: a helical ramp down into a circle, a rounded rectangle,
/// and small arcs at corners.
fn part_with_arcs_and_helices() -> Toolpath {
    let mut tp = Toolpath::new("arcs and helices");
    tp.push(Move::Spindle { rpm: 12000.0 });
    tp.push(Move::Rapid {
        to: P3::new(30.0, 20.0, 5.0),
    });
    tp.push(Move::Linear {
        to: P3::new(30.0, 20.0, 0.0),
        feed: 300.0,
    });
    let c = Point::new(20.0, 20.0);
    // three helical turns down to Z=-3, then a flat turn
    for k in 1..=3 {
        tp.push(Move::Arc {
            to: P3::new(30.0, 20.0, -(k as f64)),
            center: c,
            ccw: true,
            feed: 600.0,
        });
    }
    tp.push(Move::Arc {
        to: P3::new(30.0, 20.0, -3.0),
        center: c,
        ccw: true,
        feed: 600.0,
    });
    tp.push(Move::Rapid {
        to: P3::new(30.0, 20.0, 5.0),
    });
    // a rounded rectangle 60 x 40 with 5 mm corners, ramped in by a helical quarter
    let (x0, y0, x1, y1, rr) = (50.0, 0.0, 110.0, 40.0, 5.0);
    tp.push(Move::Rapid {
        to: P3::new(x0 + rr, y0, 5.0),
    });
    tp.push(Move::Linear {
        to: P3::new(x0 + rr, y0, -1.0),
        feed: 300.0,
    });
    tp.push(Move::Linear {
        to: P3::new(x1 - rr, y0, -1.5),
        feed: 900.0,
    });
    tp.push(Move::Arc {
        to: P3::new(x1, y0 + rr, -2.0),
        center: Point::new(x1 - rr, y0 + rr),
        ccw: true,
        feed: 900.0,
    });
    tp.push(Move::Linear {
        to: P3::new(x1, y1 - rr, -2.0),
        feed: 900.0,
    });
    tp.push(Move::Arc {
        to: P3::new(x1 - rr, y1, -2.0),
        center: Point::new(x1 - rr, y1 - rr),
        ccw: true,
        feed: 900.0,
    });
    tp.push(Move::Linear {
        to: P3::new(x0 + rr, y1, -2.0),
        feed: 900.0,
    });
    tp.push(Move::Arc {
        to: P3::new(x0, y1 - rr, -2.0),
        center: Point::new(x0 + rr, y1 - rr),
        ccw: true,
        feed: 900.0,
    });
    tp.push(Move::Linear {
        to: P3::new(x0, y0 + rr, -2.0),
        feed: 900.0,
    });
    tp.push(Move::Arc {
        to: P3::new(x0 + rr, y0, -2.0),
        center: Point::new(x0 + rr, y0 + rr),
        ccw: true,
        feed: 900.0,
    });
    // a wavy line of small clockwise and counter-clockwise arcs
    tp.push(Move::Rapid {
        to: P3::new(0.0, 60.0, 5.0),
    });
    tp.push(Move::Linear {
        to: P3::new(0.0, 60.0, -0.5),
        feed: 300.0,
    });
    for k in 0..40 {
        let x = k as f64 * 2.5;
        tp.push(Move::Arc {
            to: P3::new(x + 2.5, 60.0, -0.5),
            center: Point::new(x + 1.25, 60.0),
            ccw: k % 2 == 0,
            feed: 1200.0,
        });
    }
    tp.push(Move::Dwell { seconds: 0.5 });
    tp.push(Move::Spindle { rpm: 0.0 });
    tp
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn posted_arcs_and_helices_run_on_the_simulator_within_a_hundredth() {
    let tp = part_with_arcs_and_helices();
    let program = post(&tp, &GcodeOptions::default()).unwrap();
    let sim = GrblSim::spawn_pty(GrblSimConfig {
        time_scale: 500.0,
        ..Default::default()
    })
    .unwrap();
    let mut link = GrblLink::open(
        sim.port().to_str().unwrap(),
        GrblOptions {
            check_first: true,
            ..Default::default()
        },
    )
    .await
    .unwrap();
    let (etx, _erx) = mpsc::unbounded_channel();
    let (_ctx, crx) = watch::channel(Control::Run);
    let end = link.stream(&program, 0, etx, crx).await.unwrap();
    assert_eq!(end, StreamEnd::Completed);
    let trace = sim.trace();
    let arcs = trace
        .iter()
        .filter(|e| matches!(e.motion, Motion::ArcCw | Motion::ArcCcw))
        .count();
    assert_eq!(arcs, 4 + 4 + 40, "every arc ran as an arc");
    let dev = max_deviation(&tp, &trace);
    assert!(dev <= 0.01, "the machine strayed {dev} mm from the plan");
    // the check-mode pass received every line once more, but moved nothing
    assert_eq!(sim.received_lines(), 2 * lines(&program).len() as u64);
    assert_eq!(sim.rx_overflows(), 0);
}
