//! `GET /metrics` read with a Prometheus text-format parser: its counters match the jobs
//! the test ran (completed, cancelled, failed on a port that does not exist), on the API
//! socket and on the `--metrics-listen` address alike.

use machlink::config::Config;
use machlink::core::intake::{Input, JobSpec};
use machlink::core::store::{JobId, JobRecord, JobState};
use machlink::daemon::{Daemon, StartOptions};
use machlink::faces::client::{Client, Endpoint};
use prometheus_parse::{Scrape, Value};
use std::path::Path;
use std::time::Duration;

fn gcode(n: usize, feed: f64) -> String {
    let mut s = String::from("G21 G90\nG0 Z1\nG1 Z-0.5 F600\n");
    for i in 0..n {
        s.push_str(&format!(
            "G1 X{:.3} Y{:.3} F{feed}\n",
            (i % 20) as f64,
            (i / 20) as f64
        ));
    }
    s
}

fn job(machine: &str, text: &str) -> JobSpec {
    JobSpec {
        machine: Some(machine.into()),
        input: Input::from_bytes("part.nc", text.as_bytes().to_vec()),
        operation: None,
        tolerance: None,
        layers: Vec::new(),
        post: None,
    }
}

async fn start(dir: &Path) -> Daemon {
    let toml = format!(
        "[daemon]\nstore = \"{}\"\nsocket = \"{}\"\n\n\
         [[machine]]\nname = \"bench\"\nlink = \"sim-grbl\"\ntime_scale = 50.0\n\n\
         [[machine]]\nname = \"ghost\"\nlink = \"grbl\"\nport = \"/dev/machlink-no-such-port\"\n",
        dir.join("jobs.db").display(),
        dir.join("ml.sock").display()
    );
    let cfg = Config::parse(&toml, &dir.join("machlink.toml")).expect("config");
    Daemon::start(
        cfg,
        StartOptions {
            metrics_listen: Some("127.0.0.1:0".into()),
            ..Default::default()
        },
    )
    .await
    .expect("daemon starts")
}

async fn wait_state(c: &Client, id: JobId, want: impl Fn(JobState) -> bool) -> JobRecord {
    for _ in 0..6000 {
        let j = c.job(id).await.unwrap();
        if want(j.state) {
            return j;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    panic!("job {id} never got to the state the test waits for");
}

/// The value of one sample, by metric name and labels.
fn value(s: &Scrape, metric: &str, labels: &[(&str, &str)]) -> Option<f64> {
    s.samples
        .iter()
        .find(|x| x.metric == metric && labels.iter().all(|(k, v)| x.labels.get(k) == Some(*v)))
        .map(|x| match &x.value {
            Value::Counter(v) | Value::Gauge(v) | Value::Untyped(v) => *v,
            Value::Histogram(h) => h.last().map_or(0.0, |b| b.count),
            Value::Summary(_) => f64::NAN,
        })
}

fn parse(text: &str) -> Scrape {
    Scrape::parse(text.lines().map(|l| Ok(l.to_string()))).expect("Prometheus text format")
}

/// `GET /metrics` on the metrics-only TCP listener, by hand (HTTP/1.0).
async fn scrape_tcp(addr: std::net::SocketAddr, path: &str) -> String {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
    s.write_all(format!("GET {path} HTTP/1.0\r\nHost: x\r\n\r\n").as_bytes())
        .await
        .unwrap();
    let mut out = String::new();
    s.read_to_string(&mut out).await.unwrap();
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn metrics_counters_match_the_jobs_run() {
    let dir = tempfile::tempdir().unwrap();
    let d = start(dir.path()).await;
    let c = Client::new(Endpoint::Unix(d.socket.clone()));

    // job 1 runs; held, a second job queues behind it and is cancelled; then two more
    let mut all = c.follow(None).await.unwrap();
    let first = c.submit(&job("bench", &gcode(300, 600.0))).await.unwrap();
    // held once it streams
    loop {
        match all.next().await.unwrap() {
            Some(machlink::core::scheduler::Event::State { job, state, .. })
                if job == first.id && state == JobState::Running =>
            {
                break
            }
            Some(_) => {}
            None => panic!("the event stream ended"),
        }
    }
    c.act(first.id, "pause").await.unwrap();
    let cancelled = c.submit(&job("bench", &gcode(10, 3000.0))).await.unwrap();
    assert_eq!(
        c.act(cancelled.id, "cancel").await.unwrap().state,
        JobState::Cancelled
    );
    c.act(first.id, "resume").await.unwrap();
    let more = [
        c.submit(&job("bench", &gcode(40, 3000.0))).await.unwrap(),
        c.submit(&job("bench", &gcode(25, 3000.0))).await.unwrap(),
    ];
    let failed = c.submit(&job("ghost", &gcode(5, 3000.0))).await.unwrap();
    let mut acked = 0.0;
    for j in [&first, &more[0], &more[1]] {
        let end = wait_state(&c, j.id, |s| s.is_final()).await;
        assert_eq!(end.state, JobState::Completed, "{end:?}");
        acked += end.total_units as f64;
    }
    assert_eq!(
        wait_state(&c, failed.id, |s| s.is_final()).await.state,
        JobState::Failed
    );

    // the metrics follow the scheduler's events: wait until they have heard the last end
    let mut text = String::new();
    for _ in 0..1000 {
        text = c.text("/metrics").await.unwrap();
        let s = parse(&text);
        let done = value(
            &s,
            "machlink_jobs_finished_total",
            &[("machine", "bench"), ("state", "completed")],
        );
        let fail = value(
            &s,
            "machlink_jobs_finished_total",
            &[("machine", "ghost"), ("state", "failed")],
        );
        if done == Some(3.0) && fail == Some(1.0) {
            break;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let s = parse(&text);
    let v = |m: &str, l: &[(&str, &str)]| {
        value(&s, m, l).unwrap_or_else(|| panic!("no {m} {l:?} in:\n{text}"))
    };
    let bench = [("machine", "bench")];
    let ghost = [("machine", "ghost")];
    assert_eq!(v("machlink_jobs_submitted_total", &bench), 4.0);
    assert_eq!(v("machlink_jobs_submitted_total", &ghost), 1.0);
    assert_eq!(
        v(
            "machlink_jobs",
            &[("machine", "bench"), ("state", "completed")]
        ),
        3.0
    );
    assert_eq!(
        v(
            "machlink_jobs",
            &[("machine", "bench"), ("state", "cancelled")]
        ),
        1.0
    );
    assert_eq!(
        v(
            "machlink_jobs",
            &[("machine", "bench"), ("state", "running")]
        ),
        0.0
    );
    assert_eq!(
        v(
            "machlink_jobs",
            &[("machine", "ghost"), ("state", "failed")]
        ),
        1.0
    );
    assert_eq!(v("machlink_jobs_started_total", &bench), 3.0);
    assert_eq!(v("machlink_units_acked_total", &bench), acked);
    assert_eq!(v("machlink_units_streamed_total", &bench), acked);
    // the ghost's port cannot be opened: for its job, and again each time the daemon
    // tries to learn an idle machine's state (with backoff); the bench's link never failed
    assert!(
        v(
            "machlink_link_errors_total",
            &[("machine", "ghost"), ("error", "open")]
        ) >= 1.0
    );
    assert_eq!(
        value(
            &s,
            "machlink_link_errors_total",
            &[("machine", "bench"), ("error", "open")]
        )
        .unwrap_or(0.0),
        0.0
    );
    assert_eq!(v("machlink_rx_overflows_total", &bench), 0.0);
    assert_eq!(v("machlink_queue_depth", &bench), 0.0);
    // histograms: one planning time per job, one throughput figure per uninterrupted run
    assert_eq!(v("machlink_planning_seconds_count", &bench), 4.0);
    // job 1 ran twice (paused once; its first run may have ended before an acknowledgement)
    let runs = v("machlink_link_units_per_second_count", &bench);
    assert!((3.0..=4.0).contains(&runs), "{runs} throughput figures");

    // the metrics-only listener serves the same text, and nothing else
    let addr = d.metrics_addr.expect("a metrics address");
    let http = scrape_tcp(addr, "/metrics").await;
    let body = http.split("\r\n\r\n").nth(1).unwrap_or("");
    let s2 = parse(body);
    assert_eq!(
        value(&s2, "machlink_jobs_submitted_total", &bench),
        Some(4.0),
        "{http}"
    );
    let other = scrape_tcp(addr, "/jobs").await;
    assert!(other.starts_with("HTTP/1.0 404"), "{other}");
}
