//! The operator's commands as a shell or a script meets them, against a `machlink serve`
//! process and a simulated GRBL outside it: honest `machines` (state, age of the report),
//! `unlock`, `home`, `jog`, `override`, `pause` and `cancel` saying the state they leave,
//! `watch` writing lines (or JSON) when its output is not a terminal, `jobs` with elapsed
//! time and ETA, `resume` showing what it will do and asking first (`--yes` for scripts),
//! and a SIGTERM that holds the machine and leaves the job interrupted at its exact line.

use crate::common::cli::{
    at_socket as cli, job_record as job_json, stderr as err, stdout as out, wait_job_record,
};
use crate::proc;

use machlink::core::scheduler::Event;
use machlink::core::store::JobState;
use machlink_sim::grbl::{GrblSim, GrblSimConfig, TraceEvent};
use proc::*;
use std::process::Output;
use std::time::{Duration, Instant};

fn ok(o: &Output) {
    assert!(o.status.success(), "{}{}", out(o), err(o));
}

/// The program lines the controller received (a resume's own lines left out).
fn received(sim: &machlink_sim::grbl::GrblSimHandle) -> Vec<String> {
    sim.events()
        .into_iter()
        .filter_map(|e| match e {
            TraceEvent::Received { n: Some(_), line } if !line.contains("(resume)") => Some(line),
            _ => None,
        })
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_operator_commands_from_a_shell_and_a_graceful_sigterm() {
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
    write_config(
        dir.path(),
        &format!(
            "[[machine]]\nname = \"mill\"\nlink = \"grbl\"\nport = \"{}\"\nspindle_dwell_s = 0.5\n",
            port.display()
        ),
    );
    let mut daemon = Daemon::start(dir.path()).await;
    let sock = daemon.socket.clone();

    // machines: the live state (locked until homed) and how old the report is
    let until = Instant::now() + Duration::from_secs(30);
    let table = loop {
        let o = cli(&sock, &["machines"]);
        ok(&o);
        if out(&o).contains("alarm") {
            break out(&o);
        }
        assert!(Instant::now() < until, "{}", out(&o));
        std::thread::sleep(Duration::from_millis(100));
    };
    assert!(
        table.contains("REPORTED") && table.contains(" ago"),
        "{table}"
    );
    let o = cli(&sock, &["machines", "--json"]);
    let ms: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(ms[0]["state"]["state"], "alarm");
    assert!(ms[0]["age_ms"].as_u64().is_some(), "{ms}");

    // home, jog and unlock at the machine
    let o = cli(&sock, &["home", "mill"]);
    ok(&o);
    assert!(err(&o).contains("machine mill: homed"), "{}", err(&o));
    let o = cli(
        &sock,
        &["jog", "mill", "--x", "-4", "--y", "2.5", "--feed", "800"],
    );
    ok(&o);
    assert!(err(&o).contains("X-4.000 Y2.500"), "{}", err(&o));
    assert_eq!(sim.position(), [-4.0, 2.5, 0.0]);
    let o = cli(&sock, &["unlock", "mill"]);
    ok(&o);
    assert!(err(&o).contains("machine mill: unlocked"), "{}", err(&o));

    // a job, watched from a pipe: a line per progress step, not a progress bar
    let lines = serpentine(10, 0.0);
    let nc = dir.path().join("part.nc");
    std::fs::write(&nc, lines.join("\n")).unwrap();
    let o = cli(
        &sock,
        &["submit", nc.to_str().unwrap(), "--machine", "mill"],
    );
    ok(&o);
    let id: i64 = out(&o).trim().parse().unwrap();
    let o = cli(&sock, &["watch", &id.to_string()]);
    ok(&o);
    let w = out(&o);
    assert!(w.lines().count() >= 20, "{w}");
    assert!(w.lines().any(|l| l.contains("(50 %)")), "{w}");
    assert!(w.lines().last().unwrap().contains("completed"), "{w}");
    // `jobs` gives its elapsed time; `watch --json` an event per line
    let o = cli(&sock, &["jobs"]);
    assert!(
        out(&o).contains("ELAPSED") && out(&o).contains("ETA"),
        "{}",
        out(&o)
    );
    let o = cli(&sock, &["watch", &id.to_string(), "--json"]);
    ok(&o);
    let events: Vec<Event> = out(&o)
        .lines()
        .map(|l| serde_json::from_str(l).expect("one JSON event per line"))
        .collect();
    assert!(matches!(
        events.last(),
        Some(Event::State {
            state: JobState::Completed,
            ..
        })
    ));

    // pause, override and cancel say the state they leave the job in; a resume from a
    // line shows its plan and waits for a yes
    let o = cli(
        &sock,
        &["submit", nc.to_str().unwrap(), "--machine", "mill"],
    );
    let id2: i64 = out(&o).trim().parse().unwrap();
    wait_job_record(&sock, id2, "past unit 50", |j| j.acked_units > 50);
    let o = cli(&sock, &["override", &id2.to_string(), "--feed", "120%"]);
    ok(&o);
    assert!(err(&o).contains("feed 120 %"), "{}", err(&o));
    let o = cli(&sock, &["pause", &id2.to_string()]);
    ok(&o);
    assert!(
        err(&o).contains(&format!("job {id2} is paused")),
        "{}",
        err(&o)
    );
    let o = cli(&sock, &["cancel", &id2.to_string()]);
    ok(&o);
    assert!(
        err(&o).contains(&format!("job {id2} is cancelled")),
        "{}",
        err(&o)
    );
    let o = cli(&sock, &["resume", &id2.to_string(), "--from-line", "40"]);
    assert!(!o.status.success());
    assert!(err(&o).contains("retract"), "{}", err(&o));
    assert!(
        err(&o).contains("give --yes; nothing was sent"),
        "{}",
        err(&o)
    );
    assert_eq!(job_json(&sock, id2).state, JobState::Cancelled);

    // SIGTERM mid-job: the machine is held, the job left interrupted at its exact line
    let before = received(&sim).len();
    let o = cli(
        &sock,
        &["submit", nc.to_str().unwrap(), "--machine", "mill"],
    );
    let id3: i64 = out(&o).trim().parse().unwrap();
    wait_job_record(&sock, id3, "past unit 60", |j| j.acked_units > 60);
    let status = daemon.terminate();
    assert!(status.success(), "{status:?}\n{}", daemon.log());
    let held = sim.trace().len();
    std::thread::sleep(Duration::from_millis(400));
    assert_eq!(
        sim.trace().len(),
        held,
        "the machine moved after the daemon stopped"
    );
    let daemon2 = Daemon::start(dir.path()).await;
    let j = job_json(&sock, id3);
    assert_eq!(j.state, JobState::Interrupted, "{j:?}");
    assert!(
        j.acked_units <= j.sent_units && j.sent_units < lines.len(),
        "{j:?}"
    );
    let o = cli(&sock, &["resume", &id3.to_string(), "--yes"]);
    ok(&o);
    assert!(
        err(&o).contains(&format!("job {id3} goes on at line")),
        "{}",
        err(&o)
    );
    let done = wait_job_record(&sock, id3, "finished", |j| j.state.is_final());
    assert_eq!(
        done.state,
        JobState::Completed,
        "{done:?}\n{}",
        daemon2.log()
    );
    // every line of the third job reached the machine once, and the machine had all
    // the lines the store said it held when it stopped: the resume went on right after them
    assert_eq!(received(&sim)[before..], lines[..]);
    let mut program = 0;
    for e in sim.events() {
        if let TraceEvent::Received { n: Some(_), line } = e {
            if line.contains("(resume)") {
                break;
            }
            program += 1;
        }
    }
    assert_eq!(program - before, j.sent_units, "where the resume went on");
    assert_eq!(sim.rx_overflows(), 0);
}
