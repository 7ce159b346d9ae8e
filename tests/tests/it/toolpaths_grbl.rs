//! Tool paths from every operation (pocket with islands, profiles with tabs and lead-ins)
//! posted as GRBL G-code and streamed to the simulated GRBL over a pty: the controller
//! accepts every line, and the path it executed stays within the plan's tolerance.

use machlink_protocols::gcode::{post, Dialect, GcodeOptions};
use machlink_protocols::grbl::{GrblLink, GrblOptions};
use machlink_protocols::{Control, Link, StreamEnd};
use machlink_sim::grbl::deviation::sample_executed;
use machlink_sim::grbl::{max_deviation, GrblSim, GrblSimConfig, Motion};
use offset_core::geom::{Point, Polyline, Shape};
use offset_core::ops::{pocket, profile, PocketParams, ProfileParams, Side, Stepover};
use offset_core::{Tool, Toolpath};
use tokio::sync::{mpsc, watch};

const TOLERANCE: f64 = 0.01;

async fn run_on_grbl(name: &str, tp: &Toolpath) {
    let program = post(
        tp,
        &GcodeOptions {
            dialect: Dialect::Grbl,
            ..Default::default()
        },
    )
    .unwrap();
    let sim = GrblSim::spawn_pty(GrblSimConfig {
        time_scale: 2000.0,
        ..Default::default()
    })
    .unwrap();
    let mut link = GrblLink::open(sim.port().to_str().unwrap(), GrblOptions::default())
        .await
        .unwrap();
    let (etx, _erx) = mpsc::unbounded_channel();
    let (_ctx, crx) = watch::channel(Control::Run);
    let end = link.stream(&program, 0, etx, crx).await.unwrap();
    assert_eq!(end, StreamEnd::Completed, "{name}: the controller stopped");
    let trace = sim.trace();
    assert!(!trace.is_empty(), "{name}: nothing ran");
    // the whole plan ran: the executed cutting length matches the planned one
    let executed_cut: f64 = trace
        .iter()
        .filter(|e| e.motion != Motion::Rapid)
        .map(|e| {
            let pts = sample_executed(e);
            pts.windows(2).map(|w| w[0].dist(w[1])).sum::<f64>()
        })
        .sum();
    let (planned_cut, _) = tp.lengths();
    assert!(
        (executed_cut - planned_cut).abs() <= 1e-3 * planned_cut,
        "{name}: executed {executed_cut} mm of cuts, planned {planned_cut} mm"
    );
    let dev = max_deviation(tp, &trace);
    assert!(
        dev <= TOLERANCE,
        "{name}: the machine strayed {dev} mm from the plan"
    );
}

fn part() -> Shape {
    Shape::new(vec![
        Polyline::rect(Point::new(0.0, 0.0), Point::new(40.0, 30.0)),
        Polyline::circle(Point::new(20.0, 15.0), 5.0),
    ])
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_pocket_with_an_island_runs_on_grbl_within_the_tolerance() {
    let p = PocketParams {
        stepover: Stepover::Percent(40.0),
        cut: offset_core::ops::Cutting {
            tool: Tool::flat(6.0),
            depth: 2.0,
            stepdown: 1.0,
            tolerance: TOLERANCE,
            ..PocketParams::default().cut
        },
    };
    let tp = pocket(&part(), &p).unwrap();
    run_on_grbl("pocket", &tp).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn profiles_with_tabs_and_lead_ins_run_on_grbl_within_the_tolerance() {
    for side in [Side::Outside, Side::Inside] {
        let p = ProfileParams {
            side,
            lead_in: 2.0,
            lead_out: 2.0,
            tabs: 3,
            tab_width: 2.0,
            tab_height: 0.8,
            cut: offset_core::ops::Cutting {
                tool: Tool::flat(3.0),
                depth: 2.0,
                stepdown: 1.0,
                tolerance: TOLERANCE,
                ..ProfileParams::default().cut
            },
        };
        let tp = profile(&part(), &p).unwrap();
        run_on_grbl(&format!("profile {side:?}"), &tp).await;
    }
}
