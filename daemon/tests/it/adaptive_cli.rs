//! `--op adaptive` as an operator meets it: `plan`, `preview` and `simulate` through the
//! `machlink` binary on a plate with a round island (a 6 mm tool), the program read back and
//! replayed by `machlink simulate` against the stock (no gouge, nothing left the tool could
//! reach, no rapid or plunge through material), a bad `--engagement` as one sentence; and
//! one adaptive job streamed by `serve` to a simulated GRBL with every line once, in order.
//! The engagement bound holds on every cut at one depth but going into the plate's sharp
//! corners, which `simulate` reports apart (no path holds it there).

use crate::common;
use crate::common::cli::{at_socket as cli, stderr as err, stdout as out, wait_job_record};
use crate::proc::{write_config, Daemon};

use machlink::core::store::JobState;
use machlink_sim::grbl::{GrblSim, GrblSimConfig, TraceEvent};
use std::path::Path;

/// 30 × 20 mm with a round island of radius 2.5 at (11.5, 10).
const PLATE: &str = r#"{ "units": "mm", "paths": [
 { "closed": true, "vertices": [[0,0,0],[30,0,0],[30,20,0],[0,20,0]] },
 { "closed": true, "vertices": [[9,10,1],[14,10,1]] } ] }"#;

fn machlink(args: &[&str]) -> (bool, String, String) {
    let o = common::cli::run(args);
    (o.status.success(), out(&o), err(&o))
}

fn s(p: &Path) -> String {
    p.to_str().unwrap().to_string()
}

/// Plans the plate with `--op adaptive` at `bound`° (and `extra` options) and replays the
/// program read back from its file: the simulation's summary.
fn plan_and_simulate(dir: &Path, bound: &str, extra: &[&str]) -> String {
    let plate = dir.join("plate.json");
    std::fs::write(&plate, PLATE).unwrap();
    let nc = dir.join("plate.nc");
    let (plate, nc) = (s(&plate), s(&nc));
    let mut args = vec![
        "plan",
        &plate,
        "--op",
        "adaptive",
        "--engagement",
        bound,
        "--tool-diameter",
        "6",
        "--depth",
        "1",
        "-o",
        &nc,
    ];
    args.extend(extra);
    let (ok, _, e) = machlink(&args);
    assert!(ok, "{e}");
    let program = std::fs::read_to_string(&nc).unwrap();
    let cuts = program
        .lines()
        .filter(|l| l.starts_with("G1 X") || l.starts_with("G2") || l.starts_with("G3"))
        .count();
    assert!(cuts > 100, "{cuts} cutting lines:\n{program}");
    let (ok, summary, e) = machlink(&[
        "simulate",
        &nc,
        "--stock",
        "0,0,30,20",
        "--tool",
        "6",
        "--part",
        &plate,
        "--depth",
        "1",
        "--cell",
        "0.15",
    ]);
    assert!(ok, "{e}");
    summary
}

/// The worst engagement of a cutting move at one depth the summary names, degrees.
fn worst_level_cut(summary: &str) -> f64 {
    let line = summary
        .lines()
        .find(|l| l.trim_start().starts_with("worst engagement ") && !l.contains("going down"))
        .unwrap_or_else(|| panic!("no worst engagement in {summary}"));
    line.trim_start()["worst engagement ".len()..]
        .split('°')
        .next()
        .unwrap()
        .parse()
        .unwrap()
}

#[test]
fn an_adaptive_plan_read_back_clears_everything_the_tool_reaches_finish_pass_or_not() {
    let dir = tempfile::tempdir().unwrap();
    for extra in [&[][..], &["--finish-pass"][..]] {
        let summary = plan_and_simulate(dir.path(), "70", extra);
        for says in [
            "no gouge",
            "no material left that the tool could reach",
            "no rapid goes through material",
        ] {
            assert!(summary.contains(says), "{extra:?}: {summary}");
        }
        assert!(
            !summary.contains("straight down into material"),
            "{extra:?}: {summary}"
        );
    }
    // the preview draws it
    let svg = dir.path().join("plate.svg");
    let (ok, _, e) = machlink(&[
        "preview",
        &s(&dir.path().join("plate.json")),
        "--op",
        "adaptive",
        "--tool-diameter",
        "6",
        "-o",
        &s(&svg),
    ]);
    assert!(ok, "{e}");
    assert!(std::fs::read_to_string(&svg).unwrap().contains("<svg"));
    // a bound out of range is one sentence and a failure
    for bad in ["5", "200", "nan"] {
        let (ok, _, e) = machlink(&[
            "plan",
            &s(&dir.path().join("plate.json")),
            "--op",
            "adaptive",
            "--engagement",
            bad,
            "-o",
            &s(&dir.path().join("bad.nc")),
        ]);
        assert!(!ok, "--engagement {bad} was taken");
        assert!(
            e.contains("the engagement must be from 10° to 180°"),
            "{bad}: {e}"
        );
        assert!(!e.contains("panicked"), "{e}");
    }
}

/// The bound on every cut at one depth, as `simulate` reports it: away from the plate's
/// sharp corners (the helix entries are reported apart, "going down"); going into the
/// corners, where no path can hold it (the cutsim tests), reported apart and no more than
/// the simulation reads there with nothing to cut.
#[test]
fn an_adaptive_plan_keeps_the_engagement_bound_in_the_simulation() {
    let dir = tempfile::tempdir().unwrap();
    let summary = plan_and_simulate(dir.path(), "70", &[]);
    let worst = worst_level_cut(&summary);
    assert!(
        worst <= 70.0,
        "worst level cut {worst}° over 70°:\n{summary}"
    );
    let corners = summary
        .lines()
        .find(|l| l.contains("going into the 4 sharp corners of the walls: worst "))
        .unwrap_or_else(|| panic!("no line for the corners in {summary}"));
    let num = |after: &str| -> f64 {
        let at = corners.find(after).unwrap() + after.len();
        corners[at..].split('°').next().unwrap().parse().unwrap()
    };
    let (got, most) = (num("walls: worst "), num("up to "));
    assert!(got <= most, "{corners}");
}

/// The program lines the controller received.
fn received(sim: &machlink_sim::grbl::GrblSimHandle) -> Vec<String> {
    sim.events()
        .into_iter()
        .filter_map(|e| match e {
            TraceEvent::Received { n: Some(_), line } => Some(line),
            _ => None,
        })
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_adaptive_job_streams_to_a_simulated_grbl_every_line_once() {
    let dir = tempfile::tempdir().unwrap();
    let plate = dir.path().join("plate.json");
    std::fs::write(&plate, PLATE).unwrap();
    let port = dir.path().join("grbl0");
    let sim = GrblSim::spawn_linked(
        GrblSimConfig {
            time_scale: 200.0,
            ..Default::default()
        },
        &port,
    )
    .unwrap();
    write_config(
        dir.path(),
        &format!(
            "[[machine]]\nname = \"mill\"\nlink = \"grbl\"\nport = \"{}\"\n",
            port.display()
        ),
    );
    let daemon = Daemon::start(dir.path()).await;
    let sock = daemon.socket.clone();
    let args = [
        "--op",
        "adaptive",
        "--engagement",
        "70",
        "--tool-diameter",
        "6",
        "--depth",
        "1",
    ];
    // the program as `plan` writes it for the machine
    let nc = dir.path().join("plate.nc");
    let mut plan = vec!["plan", plate.to_str().unwrap(), "--post", "grbl", "-o"];
    plan.push(nc.to_str().unwrap());
    plan.extend(args);
    let (ok, _, e) = machlink(&plan);
    assert!(ok, "{e}");
    let lines: Vec<String> = std::fs::read_to_string(&nc)
        .unwrap()
        .lines()
        .filter(|l| !l.trim().is_empty())
        .map(str::to_string)
        .collect();
    let mut submit = vec!["submit", plate.to_str().unwrap(), "--machine", "mill"];
    submit.extend(args);
    let o = cli(&sock, &submit);
    assert!(o.status.success(), "{}", err(&o));
    let id: i64 = out(&o).trim().parse().unwrap();
    let done = wait_job_record(&sock, id, "finished", |j| j.state.is_final());
    assert_eq!(
        done.state,
        JobState::Completed,
        "{done:?}\n{}",
        daemon.log()
    );
    assert_eq!(done.op, "adaptive");
    let got = received(&sim);
    assert_eq!(got.len(), done.total_units, "{done:?}");
    assert_eq!(
        got, lines,
        "the controller's lines are the planned program's, once each"
    );
    assert_eq!(sim.rx_overflows(), 0);
}
