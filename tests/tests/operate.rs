//! Operating jobs on a simulated GRBL through the API: pause, resume, cancel, and resuming
//! a job that a crashed daemon left behind.

mod common;

use common::*;
use futures::future::BoxFuture;
use machlink::core::store::{JobState, Store};
use machlink::daemon::StartOptions;
use machlink_protocols::grbl::resume::{reposition, ResumeOptions};
use machlink_protocols::grbl::{GrblLink, GrblOptions};
use machlink_protocols::kind::{started, MachineKind, OpenLink};
use machlink_protocols::post::PostFor;
use machlink_protocols::{Control, Link, LinkError, LinkEvent, StreamEnd};
use machlink_sim::grbl::{GrblSim, GrblSimConfig};
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::{mpsc, watch, Notify};

/// The program's motion lines the machine executed, in order (the moves a resume makes
/// to bring the tool back are not the program's: they are left out).
fn executed(sim: &machlink_sim::grbl::GrblSimHandle) -> Vec<String> {
    program_motion(sim).into_iter().map(|e| e.line).collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pause_holds_the_machine_and_resume_finishes_every_line_once() {
    // slow enough that the job is still running when it is paused
    let (sim, _dir, _d, c) = grbl_cell(GrblSimConfig {
        time_scale: 10.0,
        ..Default::default()
    })
    .await;
    let lines = zigzag(400);
    let job = submit_gcode(&c, "mill", "zigzag", &lines).await;
    wait_until(&c, job.id, |j| j.acked_units >= 100).await;
    assert_eq!(
        c.act(job.id, "pause").await.unwrap().state,
        JobState::Paused
    );
    // once the machine has decelerated, nothing more is executed while held
    let mut held = executed(&sim).len();
    for _ in 0..100 {
        tokio::time::sleep(Duration::from_millis(50)).await;
        let now = executed(&sim).len();
        if now == held {
            break;
        }
        held = now;
    }
    tokio::time::sleep(Duration::from_millis(300)).await;
    assert_eq!(
        executed(&sim).len(),
        held,
        "the machine moved on while held"
    );
    assert!(held < expected_motion(&lines).len());
    let machines = c.machines().await.unwrap();
    assert_eq!(machines[0].job, Some(job.id));
    assert_eq!(
        c.act(job.id, "resume").await.unwrap().state,
        JobState::Running
    );
    let done = wait_end(&c, job.id).await;
    assert_eq!(done.state, JobState::Completed, "{:?}", done.error);
    assert_eq!(executed(&sim), expected_motion(&lines));
    assert_eq!(sim.received_lines(), lines.len() as u64);
    assert_eq!(sim.rx_overflows(), 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cancel_stops_the_machine_and_the_next_job_runs() {
    let (sim, _dir, _d, c) = grbl_cell(GrblSimConfig {
        time_scale: 10.0,
        ..Default::default()
    })
    .await;
    let lines = zigzag(2000);
    let job = submit_gcode(&c, "mill", "long", &lines).await;
    let queued = submit_gcode(&c, "mill", "queued", &zigzag(50)).await;
    wait_until(&c, job.id, |j| j.acked_units >= 100).await;
    // a queued job is cancelled at once and never runs
    assert_eq!(
        c.act(queued.id, "cancel").await.unwrap().state,
        JobState::Cancelled
    );
    c.act(job.id, "cancel").await.unwrap();
    let done = wait_end(&c, job.id).await;
    assert_eq!(done.state, JobState::Cancelled);
    assert!(done.acked_units < lines.len());
    let stopped = executed(&sim);
    // what ran is the program's beginning, each line once, and no more than was acknowledged
    let want = expected_motion(&lines);
    assert_eq!(stopped[..], want[..stopped.len()]);
    assert!(stopped.len() <= expected_motion(&lines[..done.acked_units]).len());
    tokio::time::sleep(Duration::from_millis(300)).await;
    assert_eq!(
        executed(&sim).len(),
        stopped.len(),
        "the machine moved after the cancel"
    );
    // the refused requests say why
    let e = c.act(done.id, "pause").await.unwrap_err().to_string();
    assert_eq!(
        e,
        format!("job {} is cancelled and cannot be paused", done.id)
    );
    let e = c.act(999, "cancel").await.unwrap_err().to_string();
    assert_eq!(e, "there is no job 999");
    // and the machine takes the next job
    let next = zigzag(200);
    let n = submit_gcode(&c, "mill", "next", &next).await;
    assert_eq!(wait_end(&c, n.id).await.state, JobState::Completed);
    let all = executed(&sim);
    assert_eq!(all[stopped.len()..], expected_motion(&next)[..]);
    assert_eq!(sim.rx_overflows(), 0);
}

/// A machine kind, `link = "stop-at"`, whose link streams only the first `stop_at` lines to
/// a GRBL on `port`, waits for the machine to finish them, tells the test (through the
/// `Notify` it prepared at start-up), and then hangs as a daemon would that is about to crash.
struct StopAtKind;

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct StopAtSettings {
    port: String,
    stop_at: usize,
}

impl MachineKind for StopAtKind {
    type Settings = StopAtSettings;
    type Unit = String;
    type Device = Arc<Notify>;
    fn link(&self) -> &'static str {
        "stop-at"
    }
    fn about(&self) -> &'static str {
        "a GRBL link that stops after a number of lines, as if the daemon were about to crash"
    }
    fn posts(&self) -> Vec<PostFor<String>> {
        machlink_protocols::grbl::kind::grbl_posts()
    }
    fn gcode_units(
        &self,
        lines: &[String],
        _moves: &offset_core::Toolpath,
    ) -> Option<Result<Vec<String>, machlink_protocols::PostError>> {
        Some(Ok(lines.to_vec()))
    }
    fn start(
        &self,
        _: &str,
        _: &StopAtSettings,
    ) -> BoxFuture<'static, std::io::Result<Arc<Notify>>> {
        started(Arc::new(Notify::new()))
    }
    fn open(&self, _: &str, s: &StopAtSettings, reached: &Arc<Notify>) -> OpenLink<String> {
        let (port, stop_at, reached) = (s.port.clone(), s.stop_at, reached.clone());
        Box::pin(async move {
            let link = GrblLink::open(&port, GrblOptions::default()).await?;
            Ok(Box::new(StopAtLink {
                link,
                stop_at,
                reached,
            }) as Box<dyn Link<String>>)
        })
    }
}

struct StopAtLink {
    link: GrblLink,
    stop_at: usize,
    reached: Arc<Notify>,
}

impl Link<String> for StopAtLink {
    fn stream<'a>(
        &'a mut self,
        lines: &'a [String],
        from: usize,
        events: mpsc::UnboundedSender<LinkEvent>,
        control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<StreamEnd, LinkError>> {
        Box::pin(async move {
            let head = lines[..self.stop_at].to_vec();
            let end = self
                .link
                .stream(&head, from, events.clone(), control)
                .await?;
            assert_eq!(end, StreamEnd::Completed);
            self.reached.notify_one();
            // keep the events channel open, as a live stream does, and never return
            let _keep = events;
            std::future::pending().await
        })
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_interrupted_by_a_crash_resumes_without_repeating_or_skipping_a_line() {
    let sim = GrblSim::spawn_pty(GrblSimConfig {
        time_scale: 400.0,
        ..Default::default()
    })
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let lines = zigzag(2000);
    let stop_at = 777;
    let mut registry = machlink::core::registry::standard();
    registry.add_kind(StopAtKind);
    let d = start_with(
        dir.path(),
        &format!(
            "[[machine]]\nname = \"mill\"\nlink = \"stop-at\"\nport = \"{}\"\nstop_at = {stop_at}\n",
            sim.port().display()
        ),
        &registry,
    )
    .await;
    let reached = d.device::<Arc<Notify>>("mill").unwrap().clone();
    let c = client(&d);
    let job = submit_gcode(&c, "mill", "long", &lines).await;
    tokio::time::timeout(Duration::from_secs(30), reached.notified())
        .await
        .expect("the machine ran the first part");
    // the journal catches up on its own (its timer), without the stream ending: read the
    // SQLite file through a connection of our own, as the restarted daemon will
    let store = Store::open(&dir.path().join("jobs.db")).unwrap();
    let mut journaled = 0;
    for _ in 0..300 {
        journaled = store.job(job.id).unwrap().unwrap().acked_units;
        if journaled == stop_at {
            break;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    assert_eq!(journaled, stop_at);
    d.crash().await;
    assert_eq!(
        store.job(job.id).unwrap().unwrap().state,
        JobState::Running,
        "a crash leaves the job running in the store"
    );
    // restart on the same store with the ordinary link
    let d = start(
        dir.path(),
        &machine_on(&sim.port()),
        StartOptions::default(),
    )
    .await;
    let c = client(&d);
    let j = c.job(job.id).await.unwrap();
    assert_eq!((j.state, j.acked_units), (JobState::Interrupted, stop_at));
    assert!(j.error.unwrap().contains(&format!("{stop_at} of 2000")));
    assert_eq!(c.act(job.id, "resume").await.unwrap().acked_units, stop_at);
    let done = wait_end(&c, job.id).await;
    assert_eq!(done.state, JobState::Completed, "{:?}", done.error);
    assert_eq!(done.acked_units, 2000);
    // every motion line ran once, in order, across both daemons; the only extra lines
    // the machine received are those of the resume that brought the tool back first
    assert_eq!(executed(&sim), expected_motion(&lines));
    let back = reposition(&lines, stop_at, &ResumeOptions::default()).unwrap();
    assert_eq!(
        sim.received_lines(),
        (lines.len() + back.lines.len()) as u64
    );
    assert_eq!(resume_lines(&sim).len(), back.lines.len());
    assert_eq!(sim.rx_overflows(), 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cancelled_job_restarts_from_the_line_the_operator_names() {
    let (sim, _dir, _d, c) = grbl_cell(GrblSimConfig {
        time_scale: 10.0,
        ..Default::default()
    })
    .await;
    let lines = zigzag(500);
    let job = submit_gcode(&c, "mill", "long", &lines).await;
    wait_until(&c, job.id, |j| j.acked_units >= 150).await;
    c.act(job.id, "cancel").await.unwrap();
    let stopped = wait_end(&c, job.id).await;
    assert_eq!(stopped.state, JobState::Cancelled);
    // the reset dropped what GRBL had planned but not cut: find the first program line
    // the machine did not run, as an operator would from the machine's position
    let ran = executed(&sim).len();
    let first_uncut = motions_up_to(&lines).iter().position(|&m| m > ran).unwrap();
    assert!(first_uncut <= stopped.acked_units);
    let e = c
        .resume_from_line(job.id, 5000)
        .await
        .unwrap_err()
        .to_string();
    assert_eq!(
        e,
        format!(
            "job {} has lines 1 to 500; it cannot resume from line 5000",
            job.id
        )
    );
    let j = c.resume_from_line(job.id, first_uncut + 1).await.unwrap();
    assert_eq!(j.acked_units, first_uncut);
    let done = wait_end(&c, job.id).await;
    assert_eq!(done.state, JobState::Completed, "{:?}", done.error);
    assert_eq!(executed(&sim), expected_motion(&lines));
    assert_eq!(sim.rx_overflows(), 0);
}
