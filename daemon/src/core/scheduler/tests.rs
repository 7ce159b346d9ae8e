//! Scheduler tests over an in-memory fake machine kind.

use super::*;
use futures::future::BoxFuture;
use machlink_protocols::kind::{started, MachineKind, OpenLink, Registry};
use machlink_protocols::post::PostFor;
use machlink_protocols::{Link, LinkEvent, Program, StreamEnd};
use std::sync::atomic::{AtomicUsize, Ordering};

/// A device in memory: "executes" a unit every `period`, acknowledges it, obeys hold and
/// cancel, can refuse one unit, and records what it executed.
#[derive(Clone, Default)]
struct FakeDevice {
    executed: Arc<Mutex<Vec<String>>>,
    period: Duration,
    refuse_at: Option<String>,
    /// Called when a stream starts, with the job's program (checks the store first).
    on_start: Option<Arc<dyn Fn() + Send + Sync>>,
    opens: Arc<AtomicUsize>,
}

struct FakeLink(FakeDevice);

impl Link<String> for FakeLink {
    fn stream<'a>(
        &'a mut self,
        lines: &'a [String],
        from: usize,
        events: mpsc::UnboundedSender<LinkEvent>,
        mut control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<StreamEnd, LinkError>> {
        Box::pin(async move {
            if let Some(f) = &self.0.on_start {
                f();
            }
            for (i, line) in lines.iter().enumerate().skip(from) {
                loop {
                    let c = *control.borrow_and_update();
                    match c {
                        Control::Cancel => return Ok(StreamEnd::Cancelled { acked: i }),
                        Control::Hold => {
                            let _ = events.send(LinkEvent::Status(MachineStatus {
                                state: DeviceState::Held,
                                ..Default::default()
                            }));
                            if control.changed().await.is_err() {
                                return Ok(StreamEnd::Cancelled { acked: i });
                            }
                        }
                        Control::Run => break,
                    }
                }
                if self.0.refuse_at.as_deref() == Some(line.as_str()) {
                    return Err(LinkError::Rejected {
                        unit: i,
                        text: line.clone(),
                        reason: "error:22 (feed rate has not yet been set)".into(),
                    });
                }
                tokio::time::sleep(self.0.period).await;
                self.0.executed.lock().unwrap().push(line.clone());
                let _ = events.send(LinkEvent::Acked { unit: i });
            }
            Ok(StreamEnd::Completed)
        })
    }
}

/// A machine kind whose device is a `FakeDevice` the test hands in.
struct FakeKind;

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct NoSettings {}

impl MachineKind for FakeKind {
    type Settings = NoSettings;
    type Unit = String;
    type Device = FakeDevice;
    fn link(&self) -> &'static str {
        "fake"
    }
    fn about(&self) -> &'static str {
        "a device in memory"
    }
    fn posts(&self) -> Vec<PostFor<String>> {
        machlink_protocols::grbl::kind::grbl_posts()
    }
    fn start(&self, _: &str, _: &NoSettings) -> BoxFuture<'static, std::io::Result<FakeDevice>> {
        started(FakeDevice::default())
    }
    fn open(&self, _: &str, _: &NoSettings, dev: &FakeDevice) -> OpenLink<String> {
        dev.opens.fetch_add(1, Ordering::SeqCst);
        let d = dev.clone();
        Box::pin(async move { Ok(Box::new(FakeLink(d)) as Box<dyn Link<String>>) })
    }
}

/// Machine `name` of the fake kind, running `dev`.
fn machine(name: &str, dev: &FakeDevice) -> MachineSetup {
    let mut registry = Registry::new();
    registry.add_kind(FakeKind);
    MachineSetup {
        config: MachineConfig::new(&registry, name, "fake", serde_json::json!({})).unwrap(),
        device: Arc::new(dev.clone()),
    }
}

fn program(tag: &str, n: usize) -> Program {
    Program::new(
        "grbl",
        (0..n)
            .map(|i| format!("G1 X{i} ; {tag}"))
            .collect::<Vec<String>>(),
    )
}

fn new_job(tag: &str, n: usize) -> NewJob {
    NewJob {
        machine: "mill".into(),
        op: "profile".into(),
        file_name: format!("{tag}.json"),
        params: serde_json::json!({}),
        program: program(tag, n),
    }
}

const POLICY: JournalPolicy = JournalPolicy {
    every: 7,
    max_lag: Duration::from_secs(1),
};

async fn wait_final(s: &Scheduler, id: JobId) -> JobRecord {
    let mut rx = s.subscribe();
    loop {
        let j = s.job(id).unwrap();
        if j.state.is_final() {
            return j;
        }
        let _ = tokio::time::timeout(Duration::from_millis(50), rx.recv()).await;
    }
}

async fn wait_state(s: &Scheduler, id: JobId, state: JobState) {
    for _ in 0..2000 {
        if s.job(id).unwrap().state == state {
            return;
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    panic!("job {id} never became {state}");
}

#[tokio::test]
async fn jobs_run_in_order_and_the_store_has_them_before_the_first_unit() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(&dir.path().join("s.db")).unwrap();
    let seen_before_start = Arc::new(Mutex::new(Vec::new()));
    let check_store = {
        let path = dir.path().join("s.db");
        let seen = seen_before_start.clone();
        // reads the SQLite file through its own connection: what a crash would leave
        move || {
            let other = Store::open(&path).unwrap();
            let running: Vec<_> = other.jobs_in(JobState::Running).unwrap();
            for j in running {
                let p = other.program(j.id).unwrap().decode(&FakeKind).unwrap();
                seen.lock().unwrap().push((j.id, p.len(), j.total_units));
            }
        }
    };
    let dev = FakeDevice {
        period: Duration::from_micros(200),
        on_start: Some(Arc::new(check_store)),
        ..Default::default()
    };
    let s = Scheduler::start(store, vec![machine("mill", &dev)], POLICY).unwrap();
    let a = s.submit(new_job("a", 30)).unwrap();
    let b = s.submit(new_job("b", 20)).unwrap();
    assert_eq!(a.state, JobState::Queued);
    let jb = wait_final(&s, b.id).await;
    let ja = s.job(a.id).unwrap();
    assert_eq!((ja.state, ja.acked_units), (JobState::Completed, 30));
    assert_eq!((jb.state, jb.acked_units), (JobState::Completed, 20));
    let executed = dev.executed.lock().unwrap().clone();
    let pa = program("a", 30).units::<String>().unwrap().to_vec();
    let pb = program("b", 20).units::<String>().unwrap().to_vec();
    assert_eq!(executed, [pa, pb].concat());
    assert_eq!(
        *seen_before_start.lock().unwrap(),
        vec![(a.id, 30, 30), (b.id, 20, 20)]
    );
    // journal rows in batches of 7 plus the rest: 30 → 5 flushes, 20 → 3
    assert_eq!(s.store().flush_count(), 5 + 3);
}

#[tokio::test]
async fn a_refused_line_fails_the_job_naming_it_and_the_next_job_runs() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(&dir.path().join("s.db")).unwrap();
    let dev = FakeDevice {
        refuse_at: Some("G1 X12 ; a".into()),
        ..Default::default()
    };
    let s = Scheduler::start(store, vec![machine("mill", &dev)], POLICY).unwrap();
    let a = s.submit(new_job("a", 30)).unwrap();
    let b = s.submit(new_job("b", 10)).unwrap();
    let ja = wait_final(&s, a.id).await;
    assert_eq!(ja.state, JobState::Failed);
    assert_eq!(ja.acked_units, 12);
    let msg = ja.error.unwrap();
    assert!(
        msg.contains("line 13") && msg.contains("G1 X12 ; a") && msg.contains("error:22"),
        "{msg}"
    );
    let jb = wait_final(&s, b.id).await;
    assert_eq!(jb.state, JobState::Completed);
    // a refusal leaves the link usable: the next job goes over the same one
    assert_eq!(dev.opens.load(Ordering::SeqCst), 1);
}

#[tokio::test]
async fn pause_resume_and_cancel_steer_the_stream() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(&dir.path().join("s.db")).unwrap();
    let dev = FakeDevice {
        period: Duration::from_millis(2),
        ..Default::default()
    };
    let s = Scheduler::start(store, vec![machine("mill", &dev)], POLICY).unwrap();
    let a = s.submit(new_job("a", 100)).unwrap();
    let queued = s.submit(new_job("q", 5)).unwrap();
    wait_state(&s, a.id, JobState::Running).await;
    let e = s.pause(queued.id).await.unwrap_err().to_string();
    assert!(e.contains("still queued"), "{e}");
    assert_eq!(
        s.cancel(queued.id).await.unwrap().state,
        JobState::Cancelled
    );
    assert_eq!(s.pause(a.id).await.unwrap().state, JobState::Paused);
    let held_at = dev.executed.lock().unwrap().len();
    tokio::time::sleep(Duration::from_millis(30)).await;
    // at most the unit in flight finishes during the hold
    assert!(dev.executed.lock().unwrap().len() <= held_at + 1);
    assert_eq!(s.resume(a.id).await.unwrap().state, JobState::Running);
    while dev.executed.lock().unwrap().len() < 50 {
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
    s.cancel(a.id).await.unwrap();
    let ja = wait_final(&s, a.id).await;
    assert_eq!(ja.state, JobState::Cancelled);
    let n = dev.executed.lock().unwrap().len();
    assert!(n < 100 && ja.acked_units == n, "{n} {}", ja.acked_units);
    // the cancelled queued job never ran
    assert!(dev
        .executed
        .lock()
        .unwrap()
        .iter()
        .all(|l| !l.ends_with("; q")));
    // resume restarts a cancelled job from its last acknowledged unit: no unit twice
    s.resume(a.id).await.unwrap();
    let ja = wait_final(&s, a.id).await;
    assert_eq!(ja.state, JobState::Completed);
    let pa = program("a", 100).units::<String>().unwrap().to_vec();
    assert_eq!(*dev.executed.lock().unwrap(), pa);
}

#[tokio::test]
async fn a_crash_leaves_an_interrupted_job_that_resumes_where_it_stopped() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.db");
    let dev = FakeDevice {
        period: Duration::from_millis(1),
        ..Default::default()
    };
    let s = Scheduler::start(
        Store::open(&path).unwrap(),
        vec![machine("mill", &dev)],
        POLICY,
    )
    .unwrap();
    let a = s.submit(new_job("a", 200)).unwrap();
    wait_state(&s, a.id, JobState::Running).await;
    s.pause(a.id).await.unwrap();
    // the journal catches up within its lag once the device stops acknowledging
    let executed = loop {
        let n = dev.executed.lock().unwrap().len();
        if s.job(a.id).unwrap().acked_units == n && n > 0 {
            break n;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    s.abort();
    drop(s);
    let s = Scheduler::start(
        Store::open(&path).unwrap(),
        vec![machine("mill", &dev)],
        POLICY,
    )
    .unwrap();
    let ja = s.job(a.id).unwrap();
    assert_eq!(
        (ja.state, ja.acked_units),
        (JobState::Interrupted, executed)
    );
    s.resume(a.id).await.unwrap();
    let ja = wait_final(&s, a.id).await;
    assert_eq!(ja.state, JobState::Completed);
    let pa = program("a", 200).units::<String>().unwrap().to_vec();
    assert_eq!(*dev.executed.lock().unwrap(), pa);
}

#[tokio::test]
async fn unknown_jobs_and_machines_are_refused_in_a_sentence() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(&dir.path().join("s.db")).unwrap();
    let s = Scheduler::start(store, vec![machine("mill", &FakeDevice::default())], POLICY).unwrap();
    let mut j = new_job("a", 3);
    j.machine = "lathe".into();
    assert_eq!(
        s.submit(j).unwrap_err().to_string(),
        "there is no machine `lathe` (the daemon has: `mill`)"
    );
    assert_eq!(
        s.cancel(42).await.unwrap_err().to_string(),
        "there is no job 42"
    );
    let a = s.submit(new_job("a", 3)).unwrap();
    wait_final(&s, a.id).await;
    let e = s.pause(a.id).await.unwrap_err().to_string();
    assert_eq!(e, format!("job {} is completed and cannot be paused", a.id));
}
