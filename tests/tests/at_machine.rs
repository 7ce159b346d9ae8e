//! The operator at the machine, through the daemon, against the simulated GRBL (homing
//! enabled): unlock, home and jog between jobs, overrides of a running job visible in the
//! feed the machine executed, and a sewing machine refusing what its kind cannot do.

mod common;

use common::*;
use machlink::core::scheduler::OverridePatch;
use machlink::core::store::JobState;
use machlink::daemon::StartOptions;
use machlink_protocols::{DeviceState, Operation};
use machlink_sim::grbl::interp::{clean_line, Action, Interpreter, Motion};
use machlink_sim::grbl::{GrblSim, GrblSimConfig, TraceEvent};
use std::time::Duration;

/// Squares cut one after another, a rapid between each: feeds 600 and 1200, rapids.
fn squares(n: usize) -> Vec<String> {
    let mut l = vec!["G21 G90".to_string(), "G0 Z2".to_string()];
    for i in 0..n {
        let x = (i % 10) as f64 * 12.0;
        let y = (i / 10) as f64 * 12.0;
        l.push(format!("G0 X{x:.1} Y{y:.1}"));
        l.push("G1 Z-0.5 F600".into());
        l.push(format!("G1 X{:.1} F1200", x + 8.0));
        l.push(format!("G1 Y{:.1}", y + 8.0));
        l.push(format!("G1 X{x:.1}"));
        l.push(format!("G1 Y{y:.1}"));
        l.push("G0 Z2".into());
    }
    l
}

/// The feed each move of `lines` asks for, in order (0 for rapids).
fn programmed_feeds(lines: &[String]) -> Vec<(Motion, f64)> {
    let mut i = Interpreter::new();
    let mut out = Vec::new();
    for l in lines {
        for a in i.execute(&clean_line(l)).unwrap() {
            if let Action::Move { motion, feed, .. } = a {
                out.push((motion, feed));
            }
        }
    }
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn unlock_home_jog_and_overrides_on_the_simulated_grbl() {
    let dir = tempfile::tempdir().unwrap();
    let port = dir.path().join("grbl0");
    let sim = GrblSim::spawn_linked(
        GrblSimConfig {
            time_scale: 10.0,
            homing: true,
            ..Default::default()
        },
        &port,
    )
    .unwrap();
    let d = start(
        dir.path(),
        &format!(
            "{}\n[[machine]]\nname = \"sewer\"\nlink = \"sim-sewing\"\ntime_scale = 1\n",
            machine_on(&port)
        ),
        StartOptions::default(),
    )
    .await;
    let c = client(&d);
    // homing enabled: the controller starts locked, and the daemon says so with its age
    let mill = loop {
        let m = c.machines().await.unwrap().remove(0);
        if matches!(m.status.state, DeviceState::Alarm { .. }) {
            break m;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    assert!(mill.age_ms.is_some_and(|a| a < 5000), "{mill:?}");
    // a job on a locked machine is refused, saying what to do (auto_unlock is off)
    let early = submit_gcode(&c, "mill", "early", &squares(2)).await;
    let early = wait_end(&c, early.id).await;
    assert_eq!(early.state, JobState::Failed);
    assert!(early.error.unwrap().contains("machlink unlock"));

    let said = c.operate("mill", &Operation::Unlock).await.unwrap().said;
    assert!(said.contains("unlocked"), "{said}");
    // jog 10 mm in X and 5 in Y, then home back to the machine's zero
    let said = c
        .operate(
            "mill",
            &Operation::Jog {
                x: Some(10.0),
                y: Some(5.0),
                z: None,
                feed: 600.0,
            },
        )
        .await
        .unwrap()
        .said;
    assert!(said.contains("X10.000 Y5.000"), "{said}");
    assert_eq!(sim.position(), [10.0, 5.0, 0.0]);
    let said = c.operate("mill", &Operation::Home).await.unwrap().said;
    assert!(said.contains("homed"), "{said}");
    assert_eq!(sim.position(), [0.0; 3]);
    let ev = sim.events();
    assert!(ev.contains(&TraceEvent::Unlocked) && ev.contains(&TraceEvent::Homed));
    assert!(ev.contains(&TraceEvent::Jogged {
        to: [10.0, 5.0, 0.0]
    }));
    // a jog needs an axis: refused in a sentence, nothing sent
    let e = c
        .operate(
            "mill",
            &Operation::Jog {
                x: None,
                y: None,
                z: None,
                feed: 600.0,
            },
        )
        .await
        .unwrap_err()
        .to_string();
    assert!(e.contains("at least one axis"), "{e}");

    // a job, overridden while it runs: feed 150 %, rapids 50 %
    let lines = squares(24);
    let job = submit_gcode(&c, "mill", "squares", &lines).await;
    wait_until(&c, job.id, |j| {
        j.acked_units >= 40 && j.state == JobState::Running
    })
    .await;
    // no jog while a job runs on the machine
    let e = c
        .operate(
            "mill",
            &Operation::Jog {
                x: Some(1.0),
                y: None,
                z: None,
                feed: 100.0,
            },
        )
        .await
        .unwrap_err()
        .to_string();
    assert!(
        e.contains(&format!("job {} is on machine `mill`", job.id)),
        "{e}"
    );
    let before = sim.trace().len();
    let a = c
        .override_job(
            job.id,
            &OverridePatch {
                feed: Some(150),
                rapid: Some(50),
                ..Default::default()
            },
        )
        .await
        .unwrap();
    assert_eq!(
        (a.overrides.feed, a.overrides.rapid, a.overrides.spindle),
        (150, 50, 100)
    );
    let e = c
        .override_job(
            job.id,
            &OverridePatch {
                feed: Some(250),
                ..Default::default()
            },
        )
        .await
        .unwrap_err()
        .to_string();
    assert!(e.contains("50 to 200"), "{e}");
    let done = wait_end(&c, job.id).await;
    assert_eq!(done.state, JobState::Completed, "{:?}", done.error);
    // the executed feeds: as programmed until the override, then 150 % (rapids 50 %)
    let all = sim.trace();
    let want = programmed_feeds(&lines);
    let program = &all[all.len() - want.len()..];
    assert!(before >= all.len() - want.len());
    let ratio: Vec<f64> = program
        .iter()
        .zip(&want)
        .map(|(e, (motion, f))| {
            if *motion == Motion::Rapid {
                e.feed / 5000.0
            } else {
                e.feed / f
            }
        })
        .collect();
    let first = ratio
        .iter()
        .position(|r| (r - 1.0).abs() > 1e-9)
        .expect("some moves ran overridden");
    assert!(first >= 10, "moves before the override ran at 100 %");
    assert!(ratio[..first].iter().all(|r| (r - 1.0).abs() < 1e-9));
    for (k, (r, (motion, _))) in ratio.iter().zip(&want).enumerate().skip(first + 2) {
        let want = if *motion == Motion::Rapid { 0.5 } else { 1.5 };
        assert!((r - want).abs() < 1e-9, "move {k} ran at {r}×, not {want}×");
    }
    assert!(ratio.len() - first > 50);

    // a sewing machine has no unlock and takes no overrides: refused with the reason
    let e = c
        .operate("sewer", &Operation::Unlock)
        .await
        .unwrap_err()
        .to_string();
    assert!(e.contains("unlock is not possible on this machine"), "{e}");
    let square = r#"{ "units": "mm", "paths": [ { "closed": true, "vertices": [[0,0,0],[60,0,0],[60,60,0],[0,60,0]] } ] }"#;
    let stitches = machlink::core::intake::JobSpec {
        operation: Some(machlink::core::intake::Operation::Stitch(Default::default())),
        ..common::job("sewer", "square.json", square)
    };
    let sew = c.submit(&stitches).await.unwrap();
    wait_until(&c, sew.id, |j| {
        j.state == JobState::Running && j.acked_units > 0
    })
    .await;
    let e = c
        .override_job(
            sew.id,
            &OverridePatch {
                feed: Some(120),
                ..Default::default()
            },
        )
        .await
        .unwrap_err()
        .to_string();
    assert!(e.contains("its kind takes no overrides"), "{e}");
    assert_eq!(
        c.act(sew.id, "cancel").await.unwrap().state,
        JobState::Cancelled
    );
}
