//! A fleet of three `machlink serve` processes on one nats-server, six simulated GRBL
//! machines (two per daemon, on ptys this test holds, so their traces outlive a daemon),
//! and 300 jobs submitted from this test as a fourth client. One daemon is killed with
//! SIGKILL mid-run and started again later on the same store; the test resumes the jobs it
//! left interrupted, as an operator would.
//!
//! Proven: every job is taken by exactly one daemon and stored once; every job completes;
//! the simulators executed every job's lines, each exactly once — except, in the jobs the
//! kill interrupted, the few lines that were in flight (sent, then run by the machine, but
//! never acknowledged to the dead daemon), which the resume sends again (docs/daemon.md,
//! known limits); and the fleet's job list agrees with every daemon's store.

use crate::common;

use common::nats::{start_nats, Nats};
use machlink::core::intake::{Input, JobSpec};
use machlink::core::store::{JobRecord, JobState};
use machlink::faces::client::{Client, Endpoint};
use machlink::services::fleet::client::FleetClient;
use machlink::services::fleet::FleetJob;
use machlink_sim::grbl::{GrblSim, GrblSimConfig, GrblSimHandle};
use std::collections::{BTreeMap, HashMap};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

const JOBS: usize = 300;
const MOVES: usize = 4;
const DAEMONS: usize = 3;
const MACHINES: usize = 6;

/// Job `k`'s program: modal set-up and `MOVES` moves whose X names the job and the move.
fn program(k: usize) -> String {
    let mut s = String::from("G21 G90\n");
    for i in 0..MOVES {
        s.push_str(&format!("G1 X{k}.{i} Y{}.5 F3000\n", i % 2));
    }
    s
}

/// The job and move a traced line belongs to (`G1X12.3Y1.5F3000` → (12, 3)).
fn job_and_move(line: &str) -> Option<(usize, usize)> {
    let x = line.split('X').nth(1)?.split('Y').next()?;
    let (k, i) = x.split_once('.')?;
    Some((k.parse().ok()?, i.parse().ok()?))
}

fn machine_name(m: usize) -> String {
    format!("m{m}")
}

/// A `machlink serve` process of the fleet, killed when dropped.
struct Node {
    name: String,
    dir: PathBuf,
    child: Option<Child>,
}

impl Node {
    fn config(&self) -> PathBuf {
        self.dir.join("machlink.toml")
    }

    fn socket(&self) -> PathBuf {
        self.dir.join("ml.sock")
    }

    fn start(&mut self) {
        let _ = std::fs::remove_file(self.socket());
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(self.dir.join("daemon.log"))
            .unwrap();
        let child = Command::new(env!("CARGO_BIN_EXE_machlink"))
            .args(["serve", "--log-format", "json", "--config"])
            .arg(self.config())
            .env("RUST_LOG", "info,async_nats=warn")
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .expect("machlink serve starts");
        self.child = Some(child);
    }

    /// SIGKILL: no shutdown, no flush, the store as the crash left it.
    fn kill(&mut self) {
        if let Some(mut c) = self.child.take() {
            c.kill().expect("SIGKILL");
            c.wait().unwrap();
        }
    }

    fn client(&self) -> Client {
        Client::new(Endpoint::Unix(self.socket()))
    }
}

impl Drop for Node {
    fn drop(&mut self) {
        self.kill();
    }
}

fn write_config(node: &Node, url: &str, machines: &[(String, &GrblSimHandle)]) {
    let mut toml = format!(
        "[daemon]\nstore = \"jobs.db\"\nsocket = \"ml.sock\"\njournal_every = 1\n\n\
         [fleet]\nurl = \"{url}\"\nname = \"{}\"\nack_wait_ms = 3000\n\n",
        node.name
    );
    for (name, sim) in machines {
        toml.push_str(&format!(
            "[[machine]]\nname = \"{name}\"\nlink = \"grbl\"\nport = \"{}\"\n\n",
            sim.port().display()
        ));
    }
    std::fs::write(node.config(), toml).unwrap();
}

fn spec(machine: &str, k: usize) -> JobSpec {
    JobSpec {
        machine: Some(machine.into()),
        input: Input::from_bytes(&format!("job{k}.nc"), program(k).into_bytes()),
        operation: None,
        operations: Vec::new(),
        tolerance: None,
        layers: Vec::new(),
        post: None,
    }
}

async fn fleet_jobs(f: &FleetClient) -> Vec<FleetJob> {
    f.jobs().await.expect("the fleet's job list")
}

fn count(jobs: &[FleetJob], state: &str) -> usize {
    jobs.iter().filter(|j| j.state == state).count()
}

/// Waits (bounded) until `f` holds of the fleet's job list.
async fn wait_fleet(
    f: &FleetClient,
    what: &str,
    ok: impl Fn(&[FleetJob]) -> bool,
) -> Vec<FleetJob> {
    for _ in 0..600 {
        let jobs = fleet_jobs(f).await;
        if ok(&jobs) {
            return jobs;
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    let jobs = fleet_jobs(f).await;
    let mut by_state: BTreeMap<&str, usize> = BTreeMap::new();
    for j in &jobs {
        *by_state.entry(j.state.as_str()).or_default() += 1;
    }
    panic!("the fleet never got to: {what} (its jobs by state: {by_state:?})");
}

/// How many jobs a daemon's store has completed.
async fn completed(node: &Node) -> usize {
    node.client()
        .jobs()
        .await
        .map(|j| j.iter().filter(|j| j.state == JobState::Completed).count())
        .unwrap_or(0)
}

/// Waits (bounded) until a daemon's store has completed `n` jobs.
async fn wait_completed(node: &Node, n: usize) {
    for _ in 0..3000 {
        if completed(node).await >= n {
            return;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    panic!("daemon {} never completed {n} jobs", node.name);
}

/// Waits until a simulator has stopped moving (its trace no longer grows).
async fn wait_still(sim: &GrblSimHandle) {
    let mut last = usize::MAX;
    for _ in 0..600 {
        let n = sim.trace().len();
        if n == last {
            return;
        }
        last = n;
        tokio::time::sleep(Duration::from_millis(300)).await;
    }
    panic!("a simulator never stood still");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn three_daemons_run_300_jobs_exactly_once_through_a_kill() {
    let tmp = tempfile::tempdir().unwrap();
    let nats: Nats = start_nats(tmp.path());
    let sims: Vec<GrblSimHandle> = (0..MACHINES)
        .map(|_| {
            GrblSim::spawn_pty(GrblSimConfig {
                time_scale: 10.0,
                ..Default::default()
            })
            .expect("a simulator")
        })
        .collect();
    let mut nodes: Vec<Node> = (0..DAEMONS)
        .map(|d| {
            let dir = tmp.path().join(format!("d{d}"));
            std::fs::create_dir_all(&dir).unwrap();
            Node {
                name: format!("d{d}"),
                dir,
                child: None,
            }
        })
        .collect();
    // daemon d owns machines 2d and 2d+1
    for (d, node) in nodes.iter_mut().enumerate() {
        let owned: Vec<(String, &GrblSimHandle)> = (2 * d..2 * d + 2)
            .map(|m| (machine_name(m), &sims[m]))
            .collect();
        write_config(node, &nats.url, &owned);
        node.start();
    }

    let fleet = FleetClient::connect(&nats.url, None)
        .await
        .expect("the fleet");
    for _ in 0..600 {
        if fleet.machines().await.map(|m| m.len()).unwrap_or(0) == MACHINES {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert_eq!(
        fleet.machines().await.unwrap().len(),
        MACHINES,
        "every daemon announces its machines"
    );

    // 299 jobs from this client's library, one through `machlink submit --fleet`
    let mut ids: HashMap<String, usize> = HashMap::new();
    for k in 0..JOBS - 1 {
        let job = fleet
            .submit(&spec(&machine_name(k % MACHINES), k))
            .await
            .expect("submitted");
        ids.insert(job.id, k);
    }
    let last = JOBS - 1;
    let file = tmp.path().join(format!("job{last}.nc"));
    std::fs::write(&file, program(last)).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_machlink"))
        .arg("submit")
        .arg(&file)
        .args([
            "--machine",
            &machine_name(last % MACHINES),
            "--fleet",
            &nats.url,
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    ids.insert(
        String::from_utf8_lossy(&out.stdout).trim().to_string(),
        last,
    );
    assert_eq!(ids.len(), JOBS, "every job has its own fleet id");

    // kill daemon d0 once a third of its jobs are done, while it streams
    wait_completed(&nodes[0], JOBS / DAEMONS / 3).await;
    nodes[0].kill();
    // later: the others went on without it, and its machines ran out what they had
    for node in &nodes[1..] {
        let now = completed(node).await;
        wait_completed(node, now + 10).await;
    }
    wait_still(&sims[0]).await;
    wait_still(&sims[1]).await;
    nodes[0].start();

    // the operator resumes what the kill interrupted
    let c0 = nodes[0].client();
    let mut stored0: Vec<JobRecord> = Vec::new();
    for _ in 0..600 {
        if let Ok(j) = c0.jobs().await {
            stored0 = j;
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let interrupted: Vec<JobRecord> = stored0
        .iter()
        .filter(|j| j.state == JobState::Interrupted)
        .cloned()
        .collect();
    assert!(
        interrupted.len() <= 2,
        "at most one job per machine was running: {interrupted:?}"
    );
    eprintln!(
        "after the restart d0 holds {} jobs, {} of them interrupted by the kill",
        stored0.len(),
        interrupted.len()
    );
    for j in &interrupted {
        if let Err(e) = c0.act(j.id, "resume").await {
            // the restart asks each machine about the job the kill interrupted, and a
            // machine that ran it out settles it as completed, which may happen between
            // the list above and this resume; any other refusal is a failure
            let now = c0.jobs().await.expect("the daemon's jobs");
            let state = now.iter().find(|k| k.id == j.id).map(|k| k.state);
            assert_eq!(
                state,
                Some(JobState::Completed),
                "job {} was refused a resume ({e:?}) and is not completed",
                j.id
            );
        }
    }

    let jobs = wait_fleet(&fleet, "every job completed", |j| {
        j.len() == JOBS && count(j, "completed") == JOBS
    })
    .await;

    // each job taken by exactly one daemon, stored once, and the fleet's list agrees
    let mut taken: HashMap<String, (String, JobRecord)> = HashMap::new();
    for node in &nodes {
        for j in node.client().jobs().await.expect("the daemon's jobs") {
            let id = machlink::services::fleet::node::fleet_id(&j)
                .expect("every job came from the fleet")
                .to_string();
            assert!(
                taken.insert(id.clone(), (node.name.clone(), j)).is_none(),
                "fleet job {id} was stored twice"
            );
        }
    }
    assert_eq!(taken.len(), JOBS, "every job stored, none twice");
    for fj in &jobs {
        let (daemon, local) = taken
            .get(&fj.id)
            .unwrap_or_else(|| panic!("fleet job {} is in no daemon's store", fj.id));
        assert_eq!(fj.daemon.as_deref(), Some(daemon.as_str()), "{fj:?}");
        assert_eq!(fj.local_id, Some(local.id), "{fj:?}");
        assert_eq!(fj.state, local.state.as_str(), "{fj:?}");
        assert_eq!(
            (fj.acked, fj.total),
            (local.acked_units, local.total_units),
            "{fj:?}"
        );
        assert_eq!(
            local.machine,
            machine_name(ids[&fj.id] % MACHINES),
            "{fj:?}"
        );
    }
    // `machlink jobs --fleet --json` lists the same
    let out = Command::new(env!("CARGO_BIN_EXE_machlink"))
        .args(["jobs", "--json", "--fleet", &nats.url])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let listed: Vec<FleetJob> = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(listed.len(), JOBS);

    // the simulators' traces: every move of every job, on its machine, once
    let resumed: Vec<usize> = interrupted
        .iter()
        .map(|j| {
            let id = machlink::services::fleet::node::fleet_id(j).unwrap();
            ids[id]
        })
        .collect();
    for (m, sim) in sims.iter().enumerate() {
        let mut seen: BTreeMap<(usize, usize), usize> = BTreeMap::new();
        for e in sim.trace() {
            let (k, i) = job_and_move(&e.line)
                .unwrap_or_else(|| panic!("machine {m} ran a line of no job: {}", e.line));
            assert_eq!(k % MACHINES, m, "job {k} ran on machine m{m}, not its own");
            *seen.entry((k, i)).or_default() += 1;
        }
        for k in (m..JOBS).step_by(MACHINES) {
            for i in 0..MOVES {
                let n = seen.get(&(k, i)).copied().unwrap_or(0);
                if resumed.contains(&k) {
                    // in flight at the kill: run, never acknowledged, sent again on resume
                    assert!(
                        (1..=2).contains(&n),
                        "job {k} move {i} ran {n} times on m{m}"
                    );
                } else {
                    assert_eq!(n, 1, "job {k} move {i} ran {n} times on m{m}");
                }
            }
        }
    }
    drop(nodes);
    drop(nats);
}

/// The two halves of "exactly once" at the queue, made to happen on purpose: a job handed
/// to a daemon that died before storing it is handed out again (after `ack_wait_ms`) and
/// runs; a job a daemon stored but died before acknowledging is acknowledged when it comes
/// again, and not stored or run a second time.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_not_stored_comes_again_and_a_stored_one_is_not_taken_twice() {
    use async_nats::jetstream::{self, consumer::pull};
    use futures::StreamExt;
    use machlink::core::store::{NewJob, Store};
    use machlink::services::fleet::{self, FleetMachine, Submission};

    let tmp = tempfile::tempdir().unwrap();
    let nats = start_nats(tmp.path());
    let js = jetstream::new(async_nats::connect(&nats.url).await.unwrap());
    let kv = fleet::bucket(&js).await.unwrap();
    let stream = fleet::job_stream(&js, fleet::DEFAULT_GROUP).await.unwrap();
    // the machine as its daemon announces it, and its consumer as the daemon makes it
    let announced = FleetMachine {
        name: "m0".into(),
        daemon: "d0".into(),
        group: fleet::DEFAULT_GROUP.into(),
        link: "sim-grbl".into(),
        status: Default::default(),
        job: None,
        updated_ms: 0,
    };
    kv.put("machine.m0", serde_json::to_vec(&announced).unwrap().into())
        .await
        .unwrap();
    let consumer: jetstream::consumer::Consumer<pull::Config> = stream
        .get_or_create_consumer(
            &fleet::consumer_name("m0"),
            pull::Config {
                durable_name: Some(fleet::consumer_name("m0")),
                filter_subject: fleet::job_subject(fleet::DEFAULT_GROUP, "m0"),
                ack_policy: jetstream::consumer::AckPolicy::Explicit,
                ack_wait: Duration::from_millis(500),
                ..Default::default()
            },
        )
        .await
        .unwrap();

    // job A: taken by a daemon that dies before storing it (fetched, never acknowledged)
    let client = FleetClient::connect(&nats.url, None).await.unwrap();
    let a = client.submit(&spec("m0", 1)).await.unwrap();
    let mut batch = consumer.fetch().max_messages(1).messages().await.unwrap();
    let taken = batch.next().await.expect("a delivery").unwrap();
    let first: Submission = serde_json::from_slice(&taken.payload).unwrap();
    assert_eq!(first.id, a.id);
    drop(batch);

    // job B: stored (and run) by the daemon, which died before acknowledging it
    let dir = tmp.path().join("d0");
    std::fs::create_dir_all(&dir).unwrap();
    let store = Store::open(&dir.join("jobs.db")).unwrap();
    let b_id = fleet::new_id();
    let lines: Vec<String> = program(2).lines().map(String::from).collect();
    let local_b = store
        .insert_job(&NewJob {
            machine: "m0".into(),
            op: "gcode".into(),
            file_name: "job2.nc".into(),
            params: serde_json::json!({ "fleet_id": b_id }),
            program: machlink_protocols::Program::new("gcode-file", lines),
        })
        .unwrap();
    store.set_state(local_b, JobState::Completed, None).unwrap();
    drop(store);
    js.send_publish(
        fleet::job_subject(fleet::DEFAULT_GROUP, "m0"),
        async_nats::jetstream::message::PublishMessage::build()
            .payload(
                serde_json::to_vec(&Submission {
                    id: b_id.clone(),
                    spec: spec("m0", 2),
                    submitted_ms: 0,
                })
                .unwrap()
                .into(),
            )
            .message_id(&b_id),
    )
    .await
    .unwrap()
    .await
    .unwrap();

    // the daemon comes back
    let toml = format!(
        "[daemon]\nstore = \"jobs.db\"\nsocket = \"ml.sock\"\n\n\
         [fleet]\nurl = \"{}\"\nname = \"d0\"\nack_wait_ms = 500\n\n\
         [[machine]]\nname = \"m0\"\nlink = \"sim-grbl\"\ntime_scale = 20.0\n",
        nats.url
    );
    let cfg = machlink::config::Config::parse(&toml, &dir.join("machlink.toml")).unwrap();
    let d = machlink::daemon::Daemon::start(cfg, Default::default())
        .await
        .unwrap();
    wait_fleet(&client, "job A completed", |j| {
        j.iter().any(|j| j.id == a.id && j.state == "completed")
    })
    .await;
    // B is acknowledged once seen stored: the queue empties
    let mut stream = stream;
    for _ in 0..300 {
        if stream.info().await.unwrap().state.messages == 0 {
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert_eq!(
        stream.info().await.unwrap().state.messages,
        0,
        "every job acknowledged"
    );
    let jobs = d.scheduler.jobs().unwrap();
    let ids: Vec<&str> = jobs
        .iter()
        .filter_map(machlink::services::fleet::node::fleet_id)
        .collect();
    assert_eq!(
        ids,
        [b_id.as_str(), a.id.as_str()],
        "B stored once, A stored once"
    );
    assert_eq!(jobs[0].state, JobState::Completed);
    let sim = d.device::<GrblSimHandle>("m0").unwrap();
    let ran: Vec<usize> = sim
        .trace()
        .iter()
        .filter_map(|e| job_and_move(&e.line).map(|(k, _)| k))
        .collect();
    assert_eq!(ran, vec![1; MOVES], "only A ran, once");
}
