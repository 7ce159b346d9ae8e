//! One intake: for every operation and post, the program `machlink submit` stores is the
//! program `machlink plan` writes for the same flags (layers, tolerance, a drawing in
//! inches included), byte for byte once written as the post's file. Both run through the
//! binary; the daemon runs in this process so its store can be read.

mod common;
use common::cli::run as machlink;

use futures::future::BoxFuture;
use machlink::config::Config;
use machlink::daemon::{Daemon, StartOptions};
use machlink_protocols::kind::{started, MachineKind, OpenLink};
use machlink_protocols::post::PostFor;
use machlink_protocols::{Control, Link, LinkError, LinkEvent, StreamEnd};
use std::path::{Path, PathBuf};
use tokio::sync::{mpsc, watch};

/// `link = "sink"`: a controller that takes LinuxCNC or generic G-code and acknowledges
/// every line at once (no machine in the standard kinds runs those posts).
struct SinkKind;

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct NoKeys {}

struct SinkLink;

impl Link<String> for SinkLink {
    fn stream<'a>(
        &'a mut self,
        units: &'a [String],
        from: usize,
        events: mpsc::UnboundedSender<LinkEvent>,
        _control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<StreamEnd, LinkError>> {
        Box::pin(async move {
            for i in from..units.len() {
                let _ = events.send(LinkEvent::Acked { unit: i });
            }
            Ok(StreamEnd::Completed)
        })
    }
}

impl MachineKind for SinkKind {
    type Settings = NoKeys;
    type Unit = String;
    type Device = ();
    fn link(&self) -> &'static str {
        "sink"
    }
    fn about(&self) -> &'static str {
        "takes any G-code"
    }
    fn posts(&self) -> Vec<PostFor<String>> {
        use machlink_protocols::gcode::{Dialect, GcodePost};
        vec![
            std::sync::Arc::new(GcodePost(Dialect::Linuxcnc)),
            std::sync::Arc::new(GcodePost(Dialect::Generic)),
        ]
    }
    fn start(&self, _: &str, _: &NoKeys) -> BoxFuture<'static, std::io::Result<()>> {
        started(())
    }
    fn open(&self, _: &str, _: &NoKeys, _: &()) -> OpenLink<String> {
        Box::pin(async { Ok(Box::new(SinkLink) as Box<dyn Link<String>>) })
    }
}

fn sample() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/plate-with-islands.json")
}

/// A 2 × 1 inch plate (layer CUT) and, beside it, a construction circle (layer SKETCH),
/// in inches.
const INCH_DXF: &str =
    "0\nSECTION\n2\nHEADER\n9\n$INSUNITS\n70\n1\n0\nENDSEC\n0\nSECTION\n2\nENTITIES\n\
0\nLWPOLYLINE\n8\nCUT\n90\n4\n70\n1\n10\n0\n20\n0\n10\n2\n20\n0\n10\n2\n20\n1\n10\n0\n20\n1\n\
0\nCIRCLE\n8\nSKETCH\n10\n3\n20\n0.5\n40\n0.25\n0\nENDSEC\n0\nEOF\n";

const POCKET: &str = r#"{ "units": "mm", "paths": [ { "closed": true,
  "vertices": [[-60,-40,0],[60,-40,0],[60,40,0],[0,60,0],[-60,40,0]] } ] }"#;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn submit_stores_exactly_the_program_plan_writes_for_every_operation_and_post() {
    let dir = tempfile::tempdir().unwrap();
    let dxf = dir.path().join("plate-in-inches.dxf");
    std::fs::write(&dxf, INCH_DXF).unwrap();
    let pocket = dir.path().join("pocket.json");
    std::fs::write(&pocket, POCKET).unwrap();
    let mut registry = machlink::core::registry::standard();
    registry.add_kind(SinkKind);
    let toml = format!(
        "[daemon]\nstore = \"{store}\"\nsocket = \"{sock}\"\n\n\
         [[machine]]\nname = \"router\"\nlink = \"sim-grbl\"\ntime_scale = 1000\n\n\
         [[machine]]\nname = \"lathe\"\nlink = \"sink\"\n\n\
         [[machine]]\nname = \"press\"\nlink = \"sim-modbus\"\ntime_scale = 1000\n\n\
         [[machine]]\nname = \"sewer\"\nlink = \"sim-sewing\"\ntime_scale = 1000\nspm = 3000\n",
        store = dir.path().join("jobs.db").display(),
        sock = dir.path().join("ml.sock").display()
    );
    let cfg = Config::parse_with(&toml, &dir.path().join("cell.toml"), &registry).unwrap();
    let d = Daemon::start(cfg, StartOptions::default()).await.unwrap();
    let socket = d.socket.display().to_string();

    let plate = sample().display().to_string();
    let dxf = dxf.display().to_string();
    let pocket = pocket.display().to_string();
    let profile: &[&str] = &[
        "--op",
        "profile",
        "--side",
        "inside",
        "--tool-diameter",
        "3",
        "--depth",
        "2",
        "--stepdown",
        "1",
        "--lead-in",
        "2",
        "--tabs",
        "2",
    ];
    let pocketing: &[&str] = &[
        "--op",
        "pocket",
        "--tool-diameter",
        "6",
        "--stepover",
        "50%",
        "--depth",
        "1.5",
        "--stepdown",
        "0.75",
    ];
    let layered: &[&str] = &[
        "--op",
        "profile",
        "--side",
        "outside",
        "--tool-diameter",
        "6.35",
        "--layer",
        "CUT",
        "--tolerance",
        "0.01",
    ];
    let stitching: &[&str] = &["--op", "stitch", "--stitch-length", "2.5", "--rows", "0,-3"];
    let mut cases: Vec<(&str, &[&str], &str, &str)> = Vec::new();
    for (post, machine) in [
        ("grbl", "router"),
        ("linuxcnc", "lathe"),
        ("generic", "lathe"),
        ("modbus", "press"),
    ] {
        cases.push((&plate, profile, post, machine));
        cases.push((&plate, pocketing, post, machine));
        cases.push((&dxf, layered, post, machine));
    }
    for post in ["dst", "jef"] {
        cases.push((&pocket, stitching, post, "sewer"));
    }
    for (file, flags, post, machine) in cases {
        let what = format!("{} {} --post {post}", flags.join(" "), file);
        let out = dir.path().join(format!("planned.{post}"));
        let mut args: Vec<String> = vec!["plan".into(), file.into()];
        args.extend(flags.iter().map(|s| s.to_string()));
        args.extend([
            "--post".into(),
            post.into(),
            "-o".into(),
            out.display().to_string(),
        ]);
        let args2 = args.clone();
        let o = tokio::task::spawn_blocking(move || machlink(&args2))
            .await
            .unwrap();
        assert!(
            o.status.success(),
            "plan {what}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let planned = std::fs::read(&out).unwrap();

        let mut args: Vec<String> = vec![
            "submit".into(),
            file.into(),
            "--machine".into(),
            machine.into(),
        ];
        args.extend(flags.iter().map(|s| s.to_string()));
        args.extend([
            "--post".into(),
            post.into(),
            "--socket".into(),
            socket.clone(),
        ]);
        let o = tokio::task::spawn_blocking(move || machlink(&args))
            .await
            .unwrap();
        assert!(
            o.status.success(),
            "submit {what}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let id: i64 = String::from_utf8_lossy(&o.stdout).trim().parse().unwrap();

        let kind = d.scheduler.machine_config(machine).unwrap().kind.clone();
        let program = d
            .scheduler
            .store()
            .program(id)
            .unwrap()
            .decode(kind.as_ref())
            .unwrap();
        assert_eq!(program.post(), post, "{what}");
        let label = Path::new(file)
            .file_stem()
            .unwrap()
            .to_string_lossy()
            .into_owned();
        let stored = registry.post(post).unwrap().file(&program, &label).unwrap();
        assert!(
            stored == planned,
            "{what}: the stored program ({} bytes) differs from the planned file ({} bytes)",
            stored.len(),
            planned.len()
        );
    }
    // the inch drawing came out in millimetres: its outside profile spans 2 in + the tool
    let o = machlink(&[
        "plan".into(),
        dxf.clone(),
        "--op".into(),
        "profile".into(),
        "--tool-diameter".into(),
        "6.35".into(),
        "--layer".into(),
        "CUT".into(),
        "--post".into(),
        "generic".into(),
        "-o".into(),
        dir.path().join("inch.nc").display().to_string(),
    ]);
    assert!(o.status.success());
    let tp = machlink_protocols::gcode_read::read(
        &std::fs::read_to_string(dir.path().join("inch.nc")).unwrap(),
    )
    .unwrap();
    let b = tp.bounds().unwrap();
    let width = b.max.x - b.min.x;
    assert!(
        (width - (50.8 + 6.35)).abs() < 0.01,
        "the outside profile of a 2 in plate with a 1/4 in tool spans {width} mm"
    );
    d.shutdown().await;
}
