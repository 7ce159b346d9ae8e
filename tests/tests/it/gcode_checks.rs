//! G-code jobs are checked as planned ones are: a move out of the work area (an arc by its
//! extent), a feed above the machine's limit, a settings line or an M-code the machine does
//! not allow is refused naming the line, and nothing reaches the machine.

use crate::common;

use common::*;
use machlink::core::store::JobState;
use machlink::daemon::StartOptions;
use machlink_sim::grbl::{GrblSim, GrblSimConfig, TraceEvent};

/// A GRBL machine on a simulator with a 600 × 400 × 50 mm work area and a 3000 mm/min limit.
async fn limited_cell() -> (
    machlink_sim::grbl::GrblSimHandle,
    tempfile::TempDir,
    machlink::daemon::Daemon,
) {
    let sim = GrblSim::spawn_pty(GrblSimConfig {
        time_scale: 400.0,
        ..Default::default()
    })
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let machine = format!(
        "{}max_feed = 3000\nwork_area = {{ min = [0, 0, -40], max = [600, 400, 10] }}\n",
        machine_on(&sim.port())
    );
    let d = start(dir.path(), &machine, StartOptions::default()).await;
    (sim, dir, d)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn refused_gcode_names_the_line_and_sends_nothing() {
    let (sim, _dir, d) = limited_cell().await;
    let c = client(&d);
    let cases: [(&str, &str, &[&str]); 6] = [
        (
            "out of the work area",
            "G21 G90\nG0 X900 Y10 Z5\nG1 X10 F500\n",
            &["line 2", "X 900.000", "work area"],
        ),
        (
            "over the feed limit on a rapid",
            "G21 G90\nG0 X10 Y10 F9000\nG1 X20\n",
            &["line 2", "9000 mm/min", "limit of 3000"],
        ),
        (
            "over the feed limit in inches",
            "G20 G90\n(inches)\nG1 X1 Y1 F200\n",
            &["line 3", "5080 mm/min"],
        ),
        (
            "a settings line",
            "G21\n$H\nG0 X1 Y1\n",
            &["line 2", "`$H`", "settings"],
        ),
        (
            "an arc that bulges out though both ends are inside",
            "G21 G90\nG0 X10 Y390 Z5\nG1 Z-1 F300\nG2 X50 Y390 I20 J0 F800\n",
            &["line 4", "the arc reaches Y 410.000", "work area"],
        ),
        (
            "an M-code the machine does not allow",
            "G21 G90\nG0 X1 Y1\nM6 T2\n",
            &["line 3", "M6 is not allowed"],
        ),
    ];
    for (what, text, wants) in cases {
        let e = c
            .submit(&job("mill", "cam.nc", text))
            .await
            .expect_err(what)
            .to_string();
        for want in wants {
            assert!(e.contains(want), "{what}: `{want}` not in: {e}");
        }
        assert!(e.starts_with("cam.nc, line"), "{what}: {e}");
    }
    // nothing reached the machine, nothing was stored
    assert_eq!(sim.received_lines(), 0);
    assert!(sim.trace().is_empty());
    assert!(c.jobs().await.unwrap().is_empty());

    // a program inside the limits, with tape marks and comments, runs
    let ok = "%\n(from another CAM)\nG21 G90\nG0 X10 Y10 Z5\nG1 Z-1 F300\nG3 X30 Y10 I10 J0 F800 ; a half circle\nG0 Z5\nM5\n%\n";
    let j = c.submit(&job("mill", "cam.nc", ok)).await.unwrap();
    assert_eq!(
        j.total_units, 6,
        "tape marks, comments and blank lines are not sent"
    );
    let done = wait_end(&c, j.id).await;
    assert_eq!(done.state, JobState::Completed, "{:?}", done.error);
    assert_eq!(sim.trace().len(), 4, "four moves ran");
    // a `%` in the middle is refused
    let e = c
        .submit(&job("mill", "cam.nc", "G21\n%\nG0 X1\n"))
        .await
        .unwrap_err()
        .to_string();
    assert!(e.contains("line 2") && e.contains('%'), "{e}");
}

/// bCNC's program from tests/data/gcode (lower-case words, words without spaces, a G91
/// block of R arcs) streamed to the simulated GRBL: every program line reaches it once, in
/// order, every move runs once, and the tool ends where the file's last move puts it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_program_from_bcnc_reaches_the_machine_line_by_line_once() {
    let (sim, _dir, d) = limited_cell().await;
    let c = client(&d);
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/gcode/bcnc_rounded_square.nc");
    let text = std::fs::read_to_string(&path).unwrap();
    // its comments are whole lines: the program is every other line, as written
    let program: Vec<&str> = text
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('('))
        .collect();
    let moves = program
        .iter()
        .filter(|l| l.to_ascii_uppercase().contains(['X', 'Y', 'Z']))
        .count();
    assert_eq!(
        moves, 21,
        "the file has 21 moves: 3 in, 8 a pass, 1 down, 1 up"
    );
    let j = c
        .submit(&job("mill", "bcnc_rounded_square.nc", &text))
        .await
        .unwrap();
    assert_eq!(j.total_units, program.len());
    let done = wait_end(&c, j.id).await;
    assert_eq!(done.state, JobState::Completed, "{:?}", done.error);
    let received: Vec<String> = sim
        .events()
        .into_iter()
        .filter_map(|e| match e {
            TraceEvent::Received { n: Some(_), line } => Some(line),
            _ => None,
        })
        .collect();
    assert_eq!(received, program, "every line once, in order");
    assert_eq!(sim.trace().len(), moves, "every move ran once");
    let at = sim.position();
    assert!(
        (at[0] - 20.0).abs() < 1e-3 && (at[1] - 30.0).abs() < 1e-3 && (at[2] - 3.0).abs() < 1e-3,
        "the square closes where it began, 3 mm up: {at:?}"
    );
}
