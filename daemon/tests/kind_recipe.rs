//! The recipe of docs/architecture.md followed for a throw-away kind: a pen plotter that
//! takes HPGL-like commands (`PU x,y;` pen up, `PD x,y;` pen down, in 0.025 mm plotter
//! units) over an in-memory stream and answers `ok` to each. Its settings, its post and its
//! link live only in this file; it is configured in TOML and runs a job through the daemon's
//! API. Nothing in daemon/ knows it.

use futures::future::BoxFuture;
use machlink::config::Config;
use machlink::core::intake::{Input, JobSpec, Operation};
use machlink::core::store::JobState;
use machlink::daemon::{Daemon, StartOptions};
use machlink::faces::client::{Client, Endpoint};
use machlink_protocols::kind::{started, MachineKind, OpenLink};
use machlink_protocols::post::{lines_file, Post, PostError, PostFor};
use machlink_protocols::{
    Control, DeviceState, Link, LinkError, LinkEvent, MachineStatus, StreamEnd,
};
use offset_core::toolpath::{arc_segment, Move, P3};
use offset_core::{Point, Toolpath};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::sync::{mpsc, watch};

/// Plotter units per millimetre (HPGL: 40).
const UNITS_PER_MM: f64 = 40.0;

/// `link = "plotter"`.
struct PlotterKind;

/// The keys of a plotter: how far an arc may stray from its chords when it is drawn as lines.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct PlotterSettings {
    #[serde(default = "default_chord_error")]
    chord_error_mm: f64,
}

fn default_chord_error() -> f64 {
    0.01
}

/// The plotter's post: every cutting move below Z=0 is drawn pen down, every other move pen
/// up; arcs become chords within 0.01 mm.
struct HpglPost;

impl Post for HpglPost {
    type Unit = String;
    fn name(&self) -> &'static str {
        "hpgl"
    }
    fn about(&self) -> &'static str {
        "pen-plotter commands, PU/PD in 0.025 mm"
    }
    fn extension(&self) -> &'static str {
        "hpgl"
    }
    fn units(&self, tp: &Toolpath) -> Result<Vec<String>, PostError> {
        let mut out = vec!["IN;".to_string()];
        let cmd = |down: bool, p: Point| {
            format!(
                "{}{},{};",
                if down { "PD" } else { "PU" },
                (p.x * UNITS_PER_MM).round() as i64,
                (p.y * UNITS_PER_MM).round() as i64
            )
        };
        tp.walk(P3::default(), |from, m, to| {
            let down = to.z < 0.0 && from.z < 0.0;
            match m {
                Move::Arc { center, ccw, .. } => {
                    let seg = arc_segment(from.xy(), to.xy(), *center, *ccw);
                    let r = seg.length().max(1e-9);
                    let n = (r / 0.5).ceil().max(1.0) as usize;
                    for i in 1..=n {
                        out.push(cmd(down, seg.point_at(i as f64 / n as f64)));
                    }
                }
                _ => out.push(cmd(down, to.xy())),
            }
        });
        out.push("PU;".into());
        Ok(out)
    }
    fn file(&self, units: &[String], _label: &str) -> Result<Vec<u8>, PostError> {
        Ok(lines_file(units))
    }
}

/// One pen stroke the plotter drew: pen down or up, and where it went, in plotter units.
type Stroke = (bool, i64, i64);

/// What `start` prepares for one plotter: the record of what it drew.
#[derive(Clone, Default)]
struct Plotter {
    drawn: Arc<Mutex<Vec<Stroke>>>,
}

impl MachineKind for PlotterKind {
    type Settings = PlotterSettings;
    type Unit = String;
    type Device = Plotter;
    fn link(&self) -> &'static str {
        "plotter"
    }
    fn about(&self) -> &'static str {
        "a pen plotter on an in-memory line"
    }
    fn posts(&self) -> Vec<PostFor<String>> {
        vec![Arc::new(HpglPost)]
    }
    fn check(&self, s: &PlotterSettings) -> Result<(), String> {
        if s.chord_error_mm > 0.0 {
            Ok(())
        } else {
            Err("chord_error_mm must be above 0".into())
        }
    }
    fn start(&self, _: &str, _: &PlotterSettings) -> BoxFuture<'static, std::io::Result<Plotter>> {
        started(Plotter::default())
    }
    fn open(&self, _: &str, _: &PlotterSettings, plotter: &Plotter) -> OpenLink<String> {
        let drawn = plotter.drawn.clone();
        Box::pin(async move {
            let (host, device) = tokio::io::duplex(256);
            tokio::spawn(plot(device, drawn));
            Ok(Box::new(PlotterLink {
                io: BufReader::new(host),
            }) as Box<dyn Link<String>>)
        })
    }
}

/// The plotter: reads commands, draws, answers `ok` (or `error` to what it cannot read).
async fn plot(io: tokio::io::DuplexStream, drawn: Arc<Mutex<Vec<Stroke>>>) {
    let mut io = BufReader::new(io);
    let mut line = String::new();
    while io.read_line(&mut line).await.unwrap_or(0) > 0 {
        let cmd = line.trim().trim_end_matches(';').to_string();
        line.clear();
        let reply = match (cmd.get(..2), cmd.get(2..)) {
            (Some("IN"), _) => "ok",
            (Some("PU"), Some("")) => "ok",
            (Some(p @ ("PU" | "PD")), Some(xy)) => match xy.split_once(',') {
                Some((x, y)) => match (x.parse(), y.parse()) {
                    (Ok(x), Ok(y)) => {
                        drawn.lock().unwrap().push((p == "PD", x, y));
                        "ok"
                    }
                    _ => "error",
                },
                None => "error",
            },
            _ => "error",
        };
        if io.write_all(format!("{reply}\n").as_bytes()).await.is_err() {
            return;
        }
    }
}

/// The host side: one command at a time, each acknowledged by the plotter's `ok`.
struct PlotterLink {
    io: BufReader<tokio::io::DuplexStream>,
}

impl Link<String> for PlotterLink {
    fn stream<'a>(
        &'a mut self,
        units: &'a [String],
        from: usize,
        events: mpsc::UnboundedSender<LinkEvent>,
        mut control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<StreamEnd, LinkError>> {
        Box::pin(async move {
            let status = |state| {
                LinkEvent::Status(MachineStatus {
                    state,
                    detail: "plotter".into(),
                    ..Default::default()
                })
            };
            let _ = events.send(status(DeviceState::Running));
            for (i, u) in units.iter().enumerate().skip(from) {
                loop {
                    let c = *control.borrow_and_update();
                    match c {
                        Control::Run => break,
                        Control::Cancel => return Ok(StreamEnd::Cancelled { acked: i }),
                        Control::Hold => {
                            if control.changed().await.is_err() {
                                return Ok(StreamEnd::Cancelled { acked: i });
                            }
                        }
                    }
                }
                self.io
                    .get_mut()
                    .write_all(format!("{u}\n").as_bytes())
                    .await?;
                let mut reply = String::new();
                self.io.read_line(&mut reply).await?;
                if reply.trim() != "ok" {
                    return Err(LinkError::Rejected {
                        unit: i,
                        text: u.clone(),
                        reason: format!("the plotter answered {:?}", reply.trim()),
                    });
                }
                let _ = events.send(LinkEvent::Acked { unit: i });
            }
            let _ = events.send(status(DeviceState::Idle));
            Ok(StreamEnd::Completed)
        })
    }
}

/// A 40 × 20 mm rectangle with rounded corners (radius 5): lines and arcs.
const PART: &str = r#"{ "units": "mm", "paths": [ { "closed": true, "vertices": [
  [5,0,0],[35,0,0.41421356237],[40,5,0],[40,15,0.41421356237],[35,20,0],[5,20,0.41421356237],
  [0,15,0],[0,5,0.41421356237] ] } ] }"#;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_kind_defined_in_a_test_runs_a_job_through_the_daemon() {
    let mut registry = machlink::core::registry::standard();
    registry.add_kind(PlotterKind);
    let dir = tempfile::tempdir().unwrap();
    let toml = format!(
        "[daemon]\nstore = \"{}\"\nsocket = \"{}\"\n\n[[machine]]\nname = \"pen\"\nlink = \"plotter\"\nchord_error_mm = 0.02\nwork_area = {{ min = [-10, -10, -5], max = [100, 100, 10] }}\n",
        dir.path().join("jobs.db").display(),
        dir.path().join("ml.sock").display()
    );
    let cfg = Config::parse_with(&toml, &dir.path().join("cell.toml"), &registry).unwrap();
    // a key the kind does not take is refused, naming it and its line, as for any kind
    let bad = toml.replace("chord_error_mm", "chord_eror_mm");
    let e = Config::parse_with(&bad, &dir.path().join("cell.toml"), &registry)
        .unwrap_err()
        .to_string();
    assert!(e.contains("line 8") && e.contains("`chord_eror_mm`"), "{e}");

    let d = Daemon::start(cfg, StartOptions::default()).await.unwrap();
    let c = Client::new(Endpoint::Unix(d.socket.clone()));
    let spec = JobSpec {
        machine: Some("pen".into()),
        input: Input::from_bytes("part.json", PART.as_bytes().to_vec()),
        operation: Some(Operation::Profile(offset_core::ops::ProfileParams {
            side: offset_core::ops::Side::On,
            cut: offset_core::ops::Cutting {
                depth: 0.5,
                stepdown: 0.5,
                ..Default::default()
            },
            ..Default::default()
        })),
        tolerance: Some(1e-3),
        layers: vec![],
        post: None,
    };
    let job = c.submit(&spec).await.unwrap();
    let machines = c.machines().await.unwrap();
    assert_eq!(machines[0].link, "plotter");
    // follow the job to its end
    let mut ev = c.events(job.id).await.unwrap();
    tokio::time::timeout(Duration::from_secs(30), async {
        while ev.next().await.unwrap().is_some() {}
    })
    .await
    .expect("the plot ends");
    let done = c.job(job.id).await.unwrap();
    assert_eq!(done.state, JobState::Completed, "{:?}", done.error);

    // the plotter drew every command of the post, once, in order
    let plotter = d.device::<Plotter>("pen").unwrap();
    let drawn = plotter.drawn.lock().unwrap().clone();
    assert_eq!(
        done.total_units,
        drawn.len() + 2,
        "IN; and the last PU; draw nothing"
    );
    // every pen-down stroke runs along the part's outline (within the 0.025 mm grid) …
    let outline = &offset_core::io::read_shape(PART.as_bytes(), "part.json")
        .unwrap()
        .paths[0];
    let at = |&(_, x, y): &Stroke| Point::new(x as f64 / UNITS_PER_MM, y as f64 / UNITS_PER_MM);
    let strokes: Vec<(Point, Point)> = drawn
        .windows(2)
        .filter(|w| w[1].0)
        .map(|w| (at(&w[0]), at(&w[1])))
        .collect();
    assert!(strokes.len() > 20, "{} pen-down strokes", strokes.len());
    for &(a, b) in &strokes {
        for k in 0..=10 {
            let p = a.lerp(b, k as f64 / 10.0);
            let off = outline.distance_to(p);
            assert!(
                off <= 0.03,
                "the stroke {a:?}-{b:?} strays {off} mm at {p:?}"
            );
        }
    }
    // … and the pen went all the way round: every stretch of the outline was drawn over
    for seg in outline.segments() {
        for k in 0..20 {
            let q = seg.point_at(k as f64 / 20.0);
            let near = strokes
                .iter()
                .map(|&(a, b)| offset_core::geom::Segment::Line { a, b }.distance_to(q))
                .fold(f64::MAX, f64::min);
            assert!(
                near < 0.03,
                "the outline near {q:?} was not drawn ({near} mm)"
            );
        }
    }
    d.shutdown().await;
}
