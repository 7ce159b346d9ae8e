//! Programs as other CAM programs write them (tests/data/gcode: Fusion's GRBL post, FreeCAD's
//! grbl and LinuxCNC posts, Estlcam, bCNC), through the binary: each previews as the part its
//! lines cut (cut length and extent worked out from the file by hand, the G20 one in mm),
//! passes a GRBL router's checks, runs on the simulated GRBL, and what a machine kind cannot
//! run is refused naming the line.

use crate::common;
use common::cli::{machlink, stderr, Serve};

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
    // a machine that runs a file as the moves it reads (Modbus) takes it and runs it
    let o = submit(&s, &lcnc, "ring", true);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("completed"), "{}", stderr(&o));
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
    // a sewing machine takes no G-code at all
    refused(
        &submit(&s, &data("bcnc_rounded_square.nc"), "sewer", false),
        "G-code for a sewing machine",
        &["does not run G-code files"],
    );
}
