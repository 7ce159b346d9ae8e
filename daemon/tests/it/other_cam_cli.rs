//! Programs as other CAM programs write them (tests/data/gcode: Fusion's GRBL post, FreeCAD's
//! grbl and LinuxCNC posts, Estlcam, bCNC), through the binary: each previews as the part its
//! lines cut (cut length and extent worked out from the file by hand, the G20 one in mm),
//! passes a GRBL router's checks, runs on the simulated GRBL, and what a machine kind cannot
//! run is refused naming the line.

use crate::common;
use crate::proc;
use common::cli::{at_socket as cli, machlink, stderr, stdout, wait_job_record, Serve};
use machlink::core::store::JobState;

use std::f64::consts::PI;
use std::path::{Path, PathBuf};
use std::process::{Output, Stdio};
use std::time::Duration;

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../tests/data/gcode")
        .join(name)
}

/// The line of `file` (1-based) that holds `text`.
fn line_of(file: &str, text: &str) -> usize {
    let body = std::fs::read_to_string(data(file)).unwrap();
    1 + body
        .lines()
        .position(|l| l.contains(text))
        .unwrap_or_else(|| panic!("`{text}` is not in {file}"))
}

/// The XY length and the extent [min x, min y, max x, max y] of the cuts a preview draws:
/// its paths in the line and arc colours (`M x y` then `L x y` or `A r r 0 0 sweep x y`,
/// never more than half a turn, sweep 1 counter-clockwise in the drawing's y-up group).
fn cuts_drawn(svg: &str) -> (f64, [f64; 4]) {
    let (mut len, mut bb) = (0.0, [f64::MAX, f64::MAX, f64::MIN, f64::MIN]);
    let mut grow = |x: f64, y: f64| {
        bb = [bb[0].min(x), bb[1].min(y), bb[2].max(x), bb[3].max(y)];
    };
    for el in svg.split("<path ").skip(1) {
        let colour = |c: &str| el.contains(&format!("stroke=\"{c}\""));
        if !(colour(offset_core::preview::LINEAR_COLOUR)
            || colour(offset_core::preview::ARC_COLOUR))
        {
            continue;
        }
        let d = el.split("d=\"").nth(1).unwrap().split('"').next().unwrap();
        let mut cmds: Vec<(char, Vec<f64>)> = Vec::new();
        for c in d.chars() {
            if c.is_ascii_alphabetic() {
                cmds.push((c, Vec::new()));
            }
        }
        let nums = d.split(|c: char| c.is_ascii_alphabetic()).skip(1);
        for ((_, v), text) in cmds.iter_mut().zip(nums) {
            *v = text
                .split_whitespace()
                .map(|n| n.parse().unwrap())
                .collect();
        }
        let mut at = (0.0, 0.0);
        for (c, v) in cmds {
            match c {
                'M' => {
                    at = (v[0], v[1]);
                    grow(at.0, at.1);
                }
                'L' => {
                    len += (v[0] - at.0).hypot(v[1] - at.1);
                    at = (v[0], v[1]);
                    grow(at.0, at.1);
                }
                'A' => {
                    let (r, ccw, to) = (v[0], v[4] == 1.0, (v[5], v[6]));
                    let (dx, dy) = (to.0 - at.0, to.1 - at.1);
                    let chord = dx.hypot(dy);
                    let sweep = 2.0 * (chord / (2.0 * r)).min(1.0).asin();
                    len += r * sweep;
                    // the centre of the short arc: left of the chord when counter-clockwise
                    let h = (r * r - chord * chord / 4.0).max(0.0).sqrt();
                    let (lx, ly) = (-dy / chord, dx / chord);
                    let s = if ccw { 1.0 } else { -1.0 };
                    let centre = (
                        (at.0 + to.0) / 2.0 + s * lx * h,
                        (at.1 + to.1) / 2.0 + s * ly * h,
                    );
                    let a0 = (at.1 - centre.1).atan2(at.0 - centre.0);
                    for k in 0..8 {
                        // the quadrant points the arc passes
                        let q = k as f64 * PI / 2.0 - 2.0 * PI;
                        let t = if ccw { q - a0 } else { a0 - q };
                        if (0.0..=sweep).contains(&t) || (0.0..=sweep).contains(&(t + 2.0 * PI)) {
                            grow(centre.0 + r * q.cos(), centre.1 + r * q.sin());
                        }
                    }
                    at = to;
                    grow(at.0, at.1);
                }
                other => panic!("unexpected path command {other} in {d}"),
            }
        }
    }
    (len, bb)
}

/// Each file, the XY length of its cuts and their extent, from its lines by hand (see
/// tests/data/gcode/README.md).
fn by_hand() -> [(&'static str, f64, [f64; 4]); 5] {
    [
        // bore: a circle of radius 7; contour, twice: straights 74 + 44 + 74 + 44 and four
        // quarter circles of radius 8
        (
            "fusion360_grbl_bracket.nc",
            2.0 * PI * 7.0 + 2.0 * (236.0 + 2.0 * PI * 8.0),
            [2.0, 2.0, 92.0, 62.0],
        ),
        // bore once (radius 7), profile twice (radius 33), all about (40, 40)
        (
            "freecad_grbl_flange.nc",
            2.0 * PI * 7.0 + 2.0 * 2.0 * PI * 33.0,
            [7.0, 7.0, 73.0, 73.0],
        ),
        // inches: straights 2.5 + 1.5 + 2.5 + 1.5 and a full turn of radius 0.25, once
        (
            "freecad_linuxcnc_plate_inch.ngc",
            25.4 * (8.0 + 2.0 * PI * 0.25),
            [2.54, 2.54, 78.74, 53.34],
        ),
        // the slot twice (two straights of 80, two half circles of radius 15), and three
        // quarters of a circle of radius 5 about (65, 30)
        (
            "estlcam_nameplate.nc",
            2.0 * (160.0 + 2.0 * PI * 15.0) + 1.5 * PI * 5.0,
            [5.0, 10.0, 115.0, 40.0],
        ),
        // twice: straights 30 + 40 + 30 + 40 and four quarter circles of radius 10
        (
            "bcnc_rounded_square.nc",
            2.0 * (140.0 + 2.0 * PI * 10.0),
            [20.0, 20.0, 80.0, 70.0],
        ),
    ]
}

#[test]
fn every_program_previews_as_the_part_its_lines_cut() {
    let dir = tempfile::tempdir().unwrap();
    for (file, length, extent) in by_hand() {
        let svg = dir.path().join(format!("{file}.svg"));
        let o = common::cli::run(&[
            "preview".as_ref(),
            data(file).as_os_str(),
            "-o".as_ref(),
            svg.as_os_str(),
            "--no-swept".as_ref(),
            "--no-legend".as_ref(),
            "--no-scale-bar".as_ref(),
        ]);
        assert!(o.status.success(), "{file}: {}", stderr(&o));
        let drawing = std::fs::read_to_string(&svg).unwrap();
        let (len, bb) = cuts_drawn(&drawing);
        assert!(
            (len - length).abs() < 0.01,
            "{file}: the cuts drawn are {len:.4} mm long, by hand {length:.4}"
        );
        for k in 0..4 {
            assert!(
                (bb[k] - extent[k]).abs() < 0.001,
                "{file}: the cuts drawn span {bb:?}, by hand {extent:?}"
            );
        }
    }
}

fn serve(dir: &Path) -> Serve {
    let area = "work_area = { min = [0, 0, -30], max = [300, 200, 50] }";
    let cfg = dir.join("cell.toml");
    std::fs::write(
        &cfg,
        format!(
            "[[machine]]\nname = \"bench\"\nlink = \"sim-grbl\"\ntime_scale = 400.0\nmax_feed = 3000\n{area}\n\n\
             [[machine]]\nname = \"hal\"\nlink = \"grbl\"\nport = \"/dev/machlink-no-such-port\"\n\
             allowed_m_codes = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 30]\n{area}\n\n\
             [[machine]]\nname = \"ring\"\nlink = \"sim-modbus\"\ntime_scale = 400.0\n\
             allowed_m_codes = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 30]\n{area}\n\n\
             [[machine]]\nname = \"small\"\nlink = \"sim-grbl\"\ntime_scale = 400.0\n\
             allowed_m_codes = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 30]\n\
             work_area = {{ min = [0, 0, -30], max = [50, 50, 50] }}\n\n\
             [[machine]]\nname = \"sewer\"\nlink = \"sim-sewing\"\ntime_scale = 400.0\n"
        ),
    )
    .unwrap();
    let socket = dir.join("ml.sock");
    let mut cmd = machlink();
    cmd.args(["serve", "--config"])
        .arg(&cfg)
        .arg("--socket")
        .arg(&socket)
        .stdout(Stdio::null())
        .stderr(Stdio::null());
    Serve::spawn(cmd, &socket, Duration::from_secs(20))
}

fn submit(s: &Serve, file: &Path, machine: &str, watch: bool) -> Output {
    let mut c = machlink();
    c.arg("submit")
        .arg(file)
        .args(["--machine", machine])
        .arg("--socket")
        .arg(&s.socket)
        .stdin(Stdio::null());
    if watch {
        c.arg("--watch");
    }
    c.output().expect("machlink runs")
}

/// Refused in one sentence holding every one of `wants`, exit 1, no panic.
fn refused(o: &Output, what: &str, wants: &[&str]) {
    let e = stderr(o);
    assert_eq!(o.status.code(), Some(1), "{what}: {e}");
    assert!(!e.contains("panicked"), "{what}: {e}");
    assert_eq!(
        e.matches("machlink: ").count(),
        1,
        "{what}: one sentence: {e}"
    );
    for w in wants {
        assert!(e.contains(w), "{what}: `{w}` not in: {e}");
    }
}

#[test]
fn a_grbl_router_takes_what_it_runs_and_refuses_what_it_cannot_naming_the_line() {
    let dir = tempfile::tempdir().unwrap();
    let s = serve(dir.path());
    // the three the simulated GRBL runs: checked, streamed, completed
    for file in [
        "freecad_grbl_flange.nc",
        "estlcam_nameplate.nc",
        "bcnc_rounded_square.nc",
    ] {
        let o = submit(&s, &data(file), "bench", true);
        assert!(o.status.success(), "{file}: {}", stderr(&o));
        assert!(stderr(&o).contains("completed"), "{file}: {}", stderr(&o));
    }
    // Fusion's program with its tool changer on: a GRBL refuses M6, a grblHAL that allows
    // it takes the program (its port is not there, so it is stored and fails to open)
    let fusion = data("fusion360_grbl_bracket.nc");
    let m6 = line_of("fusion360_grbl_bracket.nc", "T1 M6");
    refused(
        &submit(&s, &fusion, "bench", false),
        "M6 on a GRBL",
        &[&format!("line {m6} `N35 T1 M6`"), "M6 is not allowed"],
    );
    let o = submit(&s, &fusion, "hal", false);
    assert!(o.status.success(), "{}", stderr(&o));
    // out of a small machine's work area: the first move past X 50
    let far = line_of("fusion360_grbl_bracket.nc", "N50 G0 X54.");
    refused(
        &submit(&s, &fusion, "small", false),
        "outside the work area",
        &[&format!("line {far} "), "X 54.000", "work area (X 0 to 50)"],
    );

    // FreeCAD's LinuxCNC program: M6 and G43 H1 on a GRBL are refused at their lines, a
    // machine that runs a file as its moves takes it and runs it
    let lcnc = data("freecad_linuxcnc_plate_inch.ngc");
    let name = "freecad_linuxcnc_plate_inch.ngc";
    refused(
        &submit(&s, &lcnc, "bench", false),
        "LinuxCNC's M6 on a GRBL",
        &[&format!("line {} `M6 T1`", line_of(name, "M6 T1"))],
    );
    refused(
        &submit(&s, &lcnc, "hal", false),
        "G43 on a GRBL",
        &[
            &format!("line {} `G43 H1`", line_of(name, "G43 H1")),
            "G43 (a tool length offset",
            "GRBL 1.1",
        ],
    );
    // a machine that runs a file as the moves it reads (Modbus) takes it (and stops at its
    // tool change: a_linuxcnc_program_on_a_modbus_plc_stops_at_its_tool_change…)
    let o = submit(&s, &lcnc, "ring", false);
    assert!(o.status.success(), "{}", stderr(&o));
    // the same program without its tool change: GRBL has no canned cycles
    let text = std::fs::read_to_string(&lcnc).unwrap();
    let no_tc: Vec<&str> = text
        .lines()
        .filter(|l| !l.starts_with("M6") && !l.starts_with("G43"))
        .collect();
    let g98 = 1 + no_tc.iter().position(|l| *l == "G98").unwrap();
    let g81 = 1 + no_tc.iter().position(|l| l.starts_with("G81")).unwrap();
    let f = dir.path().join("plate_no_tool_change.ngc");
    std::fs::write(&f, no_tc.join("\n")).unwrap();
    refused(
        &submit(&s, &f, "bench", false),
        "G98 on a GRBL",
        &[
            &format!("line {g98} `G98`"),
            "G98 (a canned cycle's return height)",
        ],
    );
    let no_g98: Vec<&str> = no_tc.iter().copied().filter(|l| *l != "G98").collect();
    std::fs::write(&f, no_g98.join("\n")).unwrap();
    refused(
        &submit(&s, &f, "bench", false),
        "G81 on a GRBL",
        &[&format!("line {} `G81", g81 - 1), "G81 (a canned cycle)"],
    );

    // what no machine's checks can follow, and cutter compensation on a GRBL
    for (what, text, wants) in [
        (
            "an arc in the XZ plane",
            "G21 G90\nG0 X10 Y10 Z5\nG18\nG2 X20 Z5 I5 K0 F500\n",
            &["line 4", "XZ plane (G18)"][..],
        ),
        (
            "cutter compensation",
            "G21 G90\nG0 X10 Y10\nG41 D3\nG1 X20 F500\n",
            &["line 3", "G41 (cutter radius compensation)"][..],
        ),
    ] {
        let f = dir.path().join("other.nc");
        std::fs::write(&f, text).unwrap();
        refused(&submit(&s, &f, "bench", false), what, wants);
    }
    let f = dir.path().join("other.nc");
    std::fs::write(&f, "G21 G90\nG0 X10 Y10\nG18\nG2 X20 Z0 I5 K0 F500\n").unwrap();
    refused(
        &submit(&s, &f, "ring", false),
        "an XZ arc on Modbus",
        &["line 4", "XZ plane (G18)"],
    );
    // what a Modbus ring cannot follow, each named at its line: Fusion's retract to the
    // stored home (G28), a program stop (its ring has no stop block), another tool's length,
    // a tool change that names no tool, another work offset, a rotary axis, a probe
    let g28 = line_of("fusion360_grbl_bracket.nc", "N25 G28");
    refused(
        &submit(&s, &fusion, "ring", false),
        "G28 on Modbus",
        &[
            &format!("line {g28} `N25 G28 G91 Z0.`"),
            "G28 (a move to a stored position) is not followed",
            "machine `ring`",
        ],
    );
    for (what, text, wants) in [
        (
            "M0 on Modbus",
            "G21 G90\nG0 X10 Y10 Z5\nM0\nG1 Z-1 F300\n",
            &[
                "line 3 `M0`",
                "a program stop (M0, M1) has no block in a Modbus ring",
            ][..],
        ),
        (
            "G43 of another tool",
            "G21 G90\nT1 M6\nG43 H2\nG0 X10 Y10 Z5\n",
            &["line 3 `G43 H2`", "tool 1 is the one loaded"][..],
        ),
        (
            "G43 before any tool change",
            "G21 G90\nG43 H1\nG0 X10 Y10 Z5\n",
            &["line 2 `G43 H1`", "before a tool change (M6)"][..],
        ),
        (
            "M6 with no T",
            "G21 G90\nG0 X10 Y10 Z5\nM6\n",
            &["line 3 `M6`", "no T word"][..],
        ),
        (
            "another work offset",
            "G21 G90\nG55\nG0 X10 Y10 Z5\n",
            &["line 2 `G55`", "G55 (another work offset) is not followed"][..],
        ),
        (
            "a rotary axis",
            "G21 G90\nG0 X10 Y10 Z5\nG1 A90 F300\n",
            &[
                "line 3 `G1 A90 F300`",
                "the word A90 (an axis besides X, Y and Z)",
            ][..],
        ),
        (
            "a probe",
            "G21 G90\nG0 X10 Y10 Z5\nG38.2 Z-10 F100\n",
            &[
                "line 3 `G38.2 Z-10 F100`",
                "G38.2 (a probe) is not followed",
            ][..],
        ),
        (
            "a machine-frame move",
            "G21 G90\nG0 X10 Y10 Z5\nG53 G0 Z0\n",
            &["line 3 `G53 G0 Z0`", "G53 (a move in machine coordinates)"][..],
        ),
    ] {
        let f = dir.path().join("ring.nc");
        std::fs::write(&f, text).unwrap();
        refused(&submit(&s, &f, "ring", false), what, wants);
    }
    // the GRBL takes the probe and the machine-frame move as they are (its own G-codes)
    let f = dir.path().join("grbl_frames.nc");
    std::fs::write(&f, "G21 G90\nG0 X10 Y10 Z5\nG53 G0 Z-1\nG0 X20\n").unwrap();
    let o = submit(&s, &f, "bench", false);
    assert!(o.status.success(), "{}", stderr(&o));

    // a sewing machine takes no G-code at all
    refused(
        &submit(&s, &data("bcnc_rounded_square.nc"), "sewer", false),
        "G-code for a sewing machine",
        &["does not run G-code files"],
    );
}

/// Submits `file` to `machine` on the daemon at `sock`; the job's number.
fn submit_at(sock: &Path, file: &Path, machine: &str) -> i64 {
    let o = cli(
        sock,
        &["submit", file.to_str().unwrap(), "--machine", machine],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    stdout(&o)
        .trim()
        .parse()
        .expect("submit prints the job's number")
}

/// Waits until job `id` is paused with the note that the machine needs the operator for
/// `reason`, then checks the note says how to go on.
fn paused_for(sock: &Path, id: i64, reason: &str) {
    let j = wait_job_record(sock, id, &format!("paused for {reason}"), |j| {
        j.state == JobState::Paused && j.note.as_deref().is_some_and(|n| n.contains(reason))
    });
    assert_eq!(
        j.note.as_deref(),
        Some(format!("needs operator: {reason}, then `machlink resume {id}`").as_str())
    );
}

/// FreeCAD's LinuxCNC program (`M6 T1`, `G43 H1`, a `G81` hole, in inches) to the
/// simulated Modbus PLC through the daemon: the device holds at the tool block of T1 before
/// any move, the job names the tool from the machine's table, nothing runs until `resume`,
/// and then every block runs once, in order, the hole down to -0.25 in and the profile at
/// -0.125 in.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_linuxcnc_program_on_a_modbus_plc_stops_at_its_tool_change_until_resume() {
    use machlink_protocols::modbus::map::BlockKind;
    use machlink_sim::modbus::TraceEvent;
    let dir = tempfile::tempdir().unwrap();
    let press = proc::modbus_press(
        dir.path(),
        "allowed_m_codes = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 30]\n\
         tools = [ { number = 1, diameter = 6.35, name = \"1/4 in end mill\" } ]\n",
    )
    .await;
    let daemon = proc::Daemon::start(dir.path()).await;
    let sock = daemon.socket.clone();
    let id = submit_at(&sock, &data("freecad_linuxcnc_plate_inch.ngc"), "press");
    paused_for(&sock, id, "load T1 (1/4 in end mill)");
    let stops: Vec<(u32, u32)> = press
        .events_from(0)
        .into_iter()
        .filter_map(|e| match e {
            TraceEvent::ToolStop { seq, tool } => Some((seq, tool)),
            _ => None,
        })
        .collect();
    // M6 T1 comes before any move: the device holds at block 1, nothing run
    assert_eq!(stops, [(1, 1)]);
    let (state, _, consumed, _) = press.registers();
    assert_eq!((state, consumed), (2, 0), "held before block 1");
    std::thread::sleep(Duration::from_millis(600));
    assert_eq!(press.registers().2, 0, "a block ran during the tool change");
    assert!(
        press.trace().is_empty(),
        "a block ran during the tool change"
    );
    let o = cli(&sock, &["resume", &id.to_string(), "--yes"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let done = wait_job_record(&sock, id, "completed", |j| j.state.is_final());
    assert_eq!(done.state, JobState::Completed, "{done:?}");
    let trace = press.trace();
    let seqs: Vec<u32> = trace.iter().map(|e| e.seq).collect();
    assert_eq!(
        seqs,
        (1..=done.total_units as u32).collect::<Vec<_>>(),
        "every block once, in order"
    );
    let kinds: Vec<BlockKind> = trace.iter().map(|e| e.block.kind).collect();
    assert_eq!(kinds.first(), Some(&BlockKind::ToolChange));
    assert_eq!(
        kinds
            .iter()
            .filter(|k| **k == BlockKind::ToolChange)
            .count(),
        1
    );
    assert_eq!(kinds.last(), Some(&BlockKind::End));
    // the G81 hole to -0.25 in once, the profile at -0.125 in (micrometres)
    let z: Vec<i32> = trace.iter().map(|e| e.block.target[2]).collect();
    assert_eq!(z.iter().min(), Some(&-6350));
    assert_eq!(z.iter().filter(|z| **z == -6350).count(), 1, "{z:?}");
    assert!(z.iter().filter(|z| **z == -3175).count() >= 8, "{z:?}");
}

/// A program for a CANopen gantry (simulated CiA 402 drives behind an SLCAN adapter) with a
/// tool change (`T2 M6`) and a program stop (`M0`) before its plunge: the master comes to
/// rest at each, the job names why (the tool from the machine's table), no drive moves until
/// `resume`, and the job then ends with the plunge made once.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_canopen_gantry_stops_at_a_files_tool_change_and_its_m0_until_resume() {
    let dir = tempfile::tempdir().unwrap();
    let bus = machlink_protocols::canopen::MemoryBus::new();
    let drives = machlink_sim::canopen::SimDrives::spawn(&bus, &[1, 2, 3], 1.0);
    let adapter = machlink_sim::canopen::spawn_adapter(&bus).unwrap();
    proc::write_config(
        dir.path(),
        &format!(
            "[[machine]]\nname = \"gantry\"\nlink = \"canopen\"\nbus = \"slcan:{}\"\n\
             period_ms = 2\nheartbeat_ms = 50\nheartbeat_timeout_ms = 1500\nreport_timeout_ms = 2000\n\
             allowed_m_codes = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 30]\n\
             tools = [ {{ number = 2, diameter = 5.0, name = \"5 mm drill\" }} ]\n\
             axes = [\n  {{ axis = \"x\", node = 1, counts_per_mm = 1000, max_velocity = 60, max_acceleration = 800, max_jerk = 20000 }},\n  \
             {{ axis = \"y\", node = 2, counts_per_mm = 1000, max_velocity = 50, max_acceleration = 600, max_jerk = 20000 }},\n  \
             {{ axis = \"z\", node = 3, counts_per_mm = 1000, max_velocity = 15, max_acceleration = 400, max_jerk = 20000 }},\n]\n",
            adapter.path,
        ),
    );
    let file = dir.path().join("plunge.ngc");
    std::fs::write(
        &file,
        "%\n(a tool, a stop, one plunge)\nG21 G90\nT2\nG0 X5 Y5 Z2\nM6\nG43 H2\nM3 S8000\n\
         G0 X10 Y10\nM0 (check the clamp)\nG1 Z-1 F300\nG0 Z2\nM5\nM2\n%\n",
    )
    .unwrap();
    let daemon = proc::Daemon::start(dir.path()).await;
    let sock = daemon.socket.clone();
    let id = submit_at(&sock, &file, "gantry");
    // how far the drives have moved: set-points that changed a drive's actual position
    let moved = |drives: &machlink_sim::canopen::SimDrives| -> usize {
        drives
            .nodes()
            .iter()
            .map(|&n| {
                drives
                    .trace(n)
                    .windows(2)
                    .filter(|w| (w[1].actual - w[0].actual).abs() > 0.5)
                    .count()
            })
            .sum()
    };
    for reason in ["load T2 (5 mm drill)", "program stop"] {
        paused_for(&sock, id, reason);
        let before = moved(&drives);
        std::thread::sleep(Duration::from_millis(600));
        assert_eq!(moved(&drives), before, "a drive moved at the {reason}");
        let o = cli(&sock, &["resume", &id.to_string(), "--yes"]);
        assert!(o.status.success(), "{}", stderr(&o));
    }
    let done = wait_job_record(&sock, id, "completed", |j| j.state.is_final());
    assert_eq!(done.state, JobState::Completed, "{done:?}");
    // the plunge: Z down to -1 mm once
    let z: Vec<f64> = drives.trace(3).iter().map(|r| r.actual / 1000.0).collect();
    let dips = z
        .windows(2)
        .filter(|w| w[0] > -0.999 && w[1] <= -0.999)
        .count();
    assert_eq!(
        dips, 1,
        "the Z drive reached the plunge's depth {dips} times"
    );
}

/// Fusion's program (`G28 G91 Z0.`, `T1 M6`, `G53 G0`) streamed through the daemon to a
/// simulated controller that takes M6 as a grblHAL with a manual tool changer does (it
/// holds there until cycle start): the job pauses for T1 (named from the machine's table),
/// nothing moves until `resume`, then every program line reaches the controller once, in
/// order; the two `G28 G91 Z0.` lines go up to the stored home Z (machine 0), the cuts to
/// Z -3, and `G53 G0 X0. Y0.` ends at the machine's origin.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn fusions_program_streams_to_a_controller_that_holds_at_its_tool_change() {
    use machlink_sim::grbl::{GrblSim, GrblSimConfig, TraceEvent};
    let dir = tempfile::tempdir().unwrap();
    let port = dir.path().join("grbl0");
    let sim = GrblSim::spawn_linked(
        GrblSimConfig {
            time_scale: 40.0,
            m6_holds: true,
            ..Default::default()
        },
        &port,
    )
    .unwrap();
    proc::write_config(
        dir.path(),
        &format!(
            "[[machine]]\nname = \"hal\"\nlink = \"grbl\"\nport = \"{}\"\n\
             allowed_m_codes = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 30]\n\
             work_area = {{ min = [0, 0, -30], max = [300, 200, 50] }}\n\
             tools = [ {{ number = 1, diameter = 6.0, name = \"6 mm flat end mill\" }} ]\n",
            port.display()
        ),
    );
    let daemon = proc::Daemon::start(dir.path()).await;
    let sock = daemon.socket.clone();
    let file = data("fusion360_grbl_bracket.nc");
    let id = submit_at(&sock, &file, "hal");
    paused_for(&sock, id, "load T1 (6 mm flat end mill)");
    let executed = |sim: &machlink_sim::grbl::GrblSimHandle| sim.trace().len();
    let (moved, at) = (executed(&sim), sim.position());
    std::thread::sleep(Duration::from_millis(600));
    assert_eq!(
        (executed(&sim), sim.position()),
        (moved, at),
        "it moved during the tool change"
    );
    let o = cli(&sock, &["resume", &id.to_string(), "--yes"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let done = wait_job_record(&sock, id, "completed", |j| j.state.is_final());
    assert_eq!(done.state, JobState::Completed, "{done:?}");
    // every line of the file (comments and tape marks aside) once, in order
    let norm = |l: &str| l.replace(' ', "").to_uppercase();
    let want: Vec<String> = std::fs::read_to_string(&file)
        .unwrap()
        .lines()
        .map(machlink_protocols::gcode_read::clean)
        .filter(|l| !l.is_empty() && l != "%")
        .map(|l| norm(&l))
        .collect();
    let got: Vec<String> = sim
        .events()
        .into_iter()
        .filter_map(|e| match e {
            TraceEvent::Received { n: Some(_), line } => Some(norm(&line)),
            _ => None,
        })
        .collect();
    assert_eq!(got, want, "the controller's lines against the file's");
    let trace = sim.trace();
    let home_z: Vec<f64> = trace
        .iter()
        .filter(|e| e.line.contains("G28"))
        .map(|e| e.to[2])
        .collect();
    // each a rapid to where the tool is (G91 Z0), then Z to the stored home: at the start
    // from Z 0, at the end from Z 15
    assert_eq!(home_z, [0.0, 0.0, 15.0, 0.0]);
    let lowest = trace.iter().map(|e| e.to[2]).fold(f64::MAX, f64::min);
    assert!((lowest + 3.0).abs() < 1e-9, "the cuts reach Z {lowest}");
    let last = trace.last().unwrap();
    assert!(last.line.contains("G53"), "{last:?}");
    assert!(last.to.iter().all(|v| v.abs() < 1e-9), "{last:?}");
}
