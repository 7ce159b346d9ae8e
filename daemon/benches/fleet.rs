//! Fleet job throughput: 300 small jobs (4 moves each) submitted through NATS JetStream
//! to 6 simulated GRBL machines, owned by 3 `machlink serve` processes (2 machines each)
//! and, for comparison, by 1 process owning all 6. Wall time from the first submission to
//! the fleet's view showing every job completed. The simulators' motion finishes at once
//! and their serial lines are not paced, so the daemons and the queue are what is timed.
//!
//! `cargo bench -p machlink --bench fleet` (needs nats-server: `apt-get install nats-server`)

#[path = "../tests/common/nats.rs"]
mod nats;

use machlink::core::intake::{Input, JobSpec};
use machlink::services::fleet::client::FleetClient;
use machlink_sim::grbl::{GrblSim, GrblSimConfig, GrblSimHandle};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

const JOBS: usize = 300;
const MACHINES: usize = 6;

struct Daemon(Child);

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn program(k: usize) -> String {
    let mut s = String::from("G21 G90\n");
    for i in 0..4 {
        s.push_str(&format!("G1 X{k}.{i} Y{}.5 F3000\n", i % 2));
    }
    s
}

async fn run(daemons: usize) -> (f64, f64) {
    let tmp = tempfile::tempdir().unwrap();
    let nats = nats::start_nats(tmp.path());
    let sims: Vec<GrblSimHandle> = (0..MACHINES)
        .map(|_| {
            GrblSim::spawn_pty(GrblSimConfig {
                time_scale: f64::INFINITY,
                ..Default::default()
            })
            .unwrap()
        })
        .collect();
    let per = MACHINES / daemons;
    let mut procs = Vec::new();
    for d in 0..daemons {
        let dir = tmp.path().join(format!("d{d}"));
        std::fs::create_dir_all(&dir).unwrap();
        let mut toml = format!(
            "[daemon]\nstore = \"jobs.db\"\nsocket = \"ml.sock\"\n\n[fleet]\nurl = \"{}\"\nname = \"d{d}\"\n\n",
            nats.url
        );
        for (m, sim) in sims.iter().enumerate().skip(d * per).take(per) {
            toml.push_str(&format!(
                "[[machine]]\nname = \"m{m}\"\nlink = \"grbl\"\nport = \"{}\"\n\n",
                sim.port().display()
            ));
        }
        std::fs::write(dir.join("machlink.toml"), toml).unwrap();
        procs.push(Daemon(
            Command::new(env!("CARGO_BIN_EXE_machlink"))
                .args(["serve", "--config"])
                .arg(dir.join("machlink.toml"))
                .env("RUST_LOG", "warn")
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .unwrap(),
        ));
    }
    let fleet = FleetClient::connect(&nats.url, None).await.unwrap();
    while fleet.machines().await.map(|m| m.len()).unwrap_or(0) < MACHINES {
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let t0 = Instant::now();
    for k in 0..JOBS {
        fleet
            .submit(&JobSpec {
                machine: Some(format!("m{}", k % MACHINES)),
                input: Input::from_bytes(&format!("job{k}.nc"), program(k).into_bytes()),
                operation: None,
                tolerance: None,
                layers: Vec::new(),
                post: None,
            })
            .await
            .unwrap();
    }
    let submitted = t0.elapsed().as_secs_f64();
    loop {
        let jobs = fleet.jobs().await.unwrap();
        if jobs.iter().filter(|j| j.state == "completed").count() == JOBS {
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let all = t0.elapsed().as_secs_f64();
    drop(procs);
    (submitted, all)
}

fn main() {
    let rt = tokio::runtime::Runtime::new().unwrap();
    println!("| daemons | machines | jobs | submitted in | all completed in | jobs/s |");
    println!("|---:|---:|---:|---:|---:|---:|");
    for daemons in [3, 1] {
        let (sub, all) = rt.block_on(run(daemons));
        println!(
            "| {daemons} | {MACHINES} | {JOBS} | {sub:.2} s | {all:.2} s | {:.1} |",
            JOBS as f64 / all
        );
    }
}
