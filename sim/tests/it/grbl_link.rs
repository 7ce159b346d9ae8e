//! The GRBL link against the simulated GRBL over a real pty.

use machlink_protocols::grbl::{GrblLink, GrblOptions};
use machlink_protocols::{Control, Link, LinkError, LinkEvent, StreamEnd};
use machlink_sim::grbl::{GrblFault, GrblSim, GrblSimConfig, Motion};
use std::io::{Read, Write};
use std::time::Duration;
use tokio::sync::{mpsc, watch};

/// A deterministic random source (xorshift64*).
struct Rng(u64);
impl Rng {
    fn below(&mut self, n: u64) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) % n
    }
}

/// `n` feed moves of many line lengths (4 to ~75 bytes): short hops written with few or
/// many digits, padded with a line number or spaces, so the window holds 1 to 30 lines.
fn program_of_many_lengths(n: usize, seed: u64) -> Vec<String> {
    let mut rng = Rng(seed | 1);
    let mut lines = vec!["G21 G90 G94".to_string(), "G1 F3000".to_string()];
    let mut x = 0.0f64;
    for i in 0..n {
        x = if x > 50.0 {
            0.0
        } else {
            x + 0.1 + rng.below(5) as f64 * 0.1
        };
        let y = (i % 7) as f64 * 0.25;
        let l = match rng.below(6) {
            0 => format!("X{x:.1}"),
            1 => format!("G1 X{x:.4} Y{y:.4}"),
            2 => format!("N{i} G1 X{x:.3} Y{y:.3} Z0.000 F3000"),
            3 => format!("G1X{x:.2}Y{y:.2}"),
            4 => format!(
                "G1 X{x:.3}{}Y{y:.3}",
                " ".repeat(1 + rng.below(40) as usize)
            ),
            _ => format!("G1 X{x:.3} Y{y:.3} Z0.0000 F3000.0000 (hop {i} of many)"),
        };
        lines.push(l);
    }
    lines
}

fn channels() -> (
    mpsc::UnboundedSender<LinkEvent>,
    mpsc::UnboundedReceiver<LinkEvent>,
    watch::Sender<Control>,
    watch::Receiver<Control>,
) {
    let (etx, erx) = mpsc::unbounded_channel();
    let (ctx, crx) = watch::channel(Control::Run);
    (etx, erx, ctx, crx)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_thousand_lines_of_many_lengths_each_run_once_in_order_without_overflow() {
    let sim = GrblSim::spawn_pty(GrblSimConfig {
        time_scale: 400.0,
        ..Default::default()
    })
    .unwrap();
    let port = sim.port();
    let mut link = GrblLink::open(port.to_str().unwrap(), GrblOptions::default())
        .await
        .unwrap();
    assert_eq!(link.window(), 128);
    let lines = program_of_many_lengths(2100, 42);
    let program = lines.clone();
    let (etx, mut erx, _ctx, crx) = channels();
    let end = link.stream(&program, 0, etx, crx).await.unwrap();
    assert_eq!(end, StreamEnd::Completed);
    assert_eq!(sim.rx_overflows(), 0);
    assert_eq!(sim.received_lines(), lines.len() as u64);
    let trace = sim.trace();
    // the two header lines do not move; every other line moved exactly once, in order
    let indices: Vec<u64> = trace.iter().map(|e| e.index).collect();
    let expected: Vec<u64> = (3..=lines.len() as u64).collect();
    assert_eq!(indices, expected);
    for e in &trace {
        let sent = &lines[e.index as usize - 1];
        let cleaned: String = sent
            .split('(')
            .next()
            .unwrap()
            .chars()
            .filter(|c| !c.is_whitespace())
            .collect();
        assert_eq!(e.line, cleaned, "line {} arrived intact", e.index);
        assert_eq!(e.motion, Motion::Linear);
    }
    let mut acked = Vec::new();
    let mut statuses = 0;
    while let Ok(ev) = erx.try_recv() {
        match ev {
            LinkEvent::Acked { unit } => acked.push(unit),
            LinkEvent::Status(_) => statuses += 1,
            LinkEvent::Message(_) => {}
        }
    }
    assert_eq!(acked, (0..lines.len()).collect::<Vec<_>>());
    assert!(statuses >= 1);
    sim.shutdown();
}

#[test]
fn a_client_that_ignores_the_window_overflows_the_receive_buffer() {
    // the negative control: a program of the same kind, written in 64-byte chunks without
    // waiting for any ok, to a controller whose planner fills
    let sim = GrblSim::spawn_pty(GrblSimConfig {
        time_scale: 20.0,
        ..Default::default()
    })
    .unwrap();
    let port = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(sim.port())
        .unwrap();
    let mut reader = port.try_clone().unwrap();
    let replies = std::thread::spawn(move || {
        let mut all = Vec::new();
        let mut buf = [0u8; 4096];
        while let Ok(n) = reader.read(&mut buf) {
            if n == 0 {
                break;
            }
            all.extend_from_slice(&buf[..n]);
        }
        String::from_utf8_lossy(&all).into_owned()
    });
    let lines = program_of_many_lengths(400, 7);
    let mut bytes = Vec::new();
    for l in &lines {
        bytes.extend_from_slice(l.as_bytes());
        bytes.push(b'\n');
    }
    let mut writer = port;
    for chunk in bytes.chunks(64) {
        writer.write_all(chunk).unwrap();
        std::thread::sleep(Duration::from_millis(2));
    }
    std::thread::sleep(Duration::from_millis(500));
    let overflows = sim.rx_overflows();
    let received = sim.received_lines();
    // closing the simulator's side ends the reader
    sim.shutdown();
    let replies = replies.join().unwrap();
    assert!(overflows > 0, "no bytes were dropped");
    assert!(
        received < lines.len() as u64,
        "dropped bytes merge or lose lines"
    );
    // the controller rejects the spliced lines it does get
    assert!(replies.contains("error:"), "{replies}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn check_mode_finds_a_bad_line_before_anything_moves() {
    let sim = GrblSim::spawn_pty(GrblSimConfig {
        time_scale: 200.0,
        ..Default::default()
    })
    .unwrap();
    let opts = GrblOptions {
        check_first: true,
        ..Default::default()
    };
    let mut link = GrblLink::open(sim.port().to_str().unwrap(), opts)
        .await
        .unwrap();
    let mut lines = program_of_many_lengths(300, 11);
    // an arc whose end is not on its circle: GRBL's error:33
    lines[200] = "G2 X10 Y0 I3 J0".to_string();
    let (etx, _erx, _ctx, crx) = channels();
    let err = link.stream(&lines.clone(), 0, etx, crx).await.unwrap_err();
    let LinkError::Rejected { unit, reason, .. } = &err else {
        panic!("expected a rejection, got {err}");
    };
    assert_eq!(*unit, 200);
    assert!(
        reason.starts_with("error:33") && reason.contains("check mode"),
        "{reason}"
    );
    assert!(sim.trace().is_empty(), "nothing moved");
    // the controller left check mode: the fixed program runs for real
    lines[200] = "G1 X10 Y0".to_string();
    let (etx, _erx, _ctx, crx) = channels();
    let end = link.stream(&lines.clone(), 0, etx, crx).await.unwrap();
    assert_eq!(end, StreamEnd::Completed);
    assert_eq!(sim.trace().len(), lines.len() - 2);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_command_line_simulator_serves_a_link_through_its_symlink() {
    let dir = tempfile::tempdir().unwrap();
    let link_path = dir.path().join("grbl0");
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_machlink-sim"))
        .args(["grbl", "--pty"])
        .arg(&link_path)
        .args(["--time-scale", "inf", "--error-at", "5:20"])
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut out = std::io::BufReader::new(child.stdout.take().unwrap());
    let mut printed = String::new();
    std::io::BufRead::read_line(&mut out, &mut printed).unwrap();
    assert_eq!(printed.trim(), link_path.to_str().unwrap());
    let result = async {
        let mut link = GrblLink::open(link_path.to_str().unwrap(), GrblOptions::default()).await?;
        let lines = program_of_many_lengths(20, 2);
        let (etx, _erx, _ctx, crx) = channels();
        link.stream(&lines, 0, etx, crx).await
    }
    .await;
    let _ = child.kill();
    let _ = child.wait();
    match result {
        Err(LinkError::Rejected {
            unit: 4, reason, ..
        }) => assert!(reason.starts_with("error:20")),
        other => panic!("expected error:20 at the fifth line, got {other:?}"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_injected_error_names_the_line_and_the_next_program_runs() {
    let sim = GrblSim::spawn_pty(GrblSimConfig {
        time_scale: 200.0,
        faults: vec![GrblFault::ErrorAtLine {
            line: 150,
            code: 20,
        }],
        ..Default::default()
    })
    .unwrap();
    let mut link = GrblLink::open(sim.port().to_str().unwrap(), GrblOptions::default())
        .await
        .unwrap();
    let lines = program_of_many_lengths(400, 3);
    let (etx, _erx, _ctx, crx) = channels();
    let err = link.stream(&lines.clone(), 0, etx, crx).await.unwrap_err();
    let LinkError::Rejected { unit, text, reason } = &err else {
        panic!("expected a rejection, got {err}");
    };
    assert_eq!(*unit, 149);
    assert_eq!(text, &lines[149]);
    assert!(
        reason.starts_with("error:20 (Unsupported command"),
        "{reason}"
    );
    assert!(err.to_string().contains(&lines[149]));
    // The rejected line did not move. GRBL goes on with the lines behind it in its
    // receive buffer until the link's feed hold and reset reach it (as the real
    // controller does), so a line after it may move only if it was already in that
    // buffer when the error came: character counting kept the unanswered lines, the
    // rejected one first, within the buffer, and nothing is sent after an error.
    let rx = GrblSimConfig::default().rx_buffer;
    let in_buffer =
        |index: u64| -> usize { lines[149..index as usize].iter().map(|l| l.len() + 1).sum() };
    for e in sim.trace() {
        assert_ne!(e.index, 150, "the rejected line moved: {e:?}");
        if e.index > 150 {
            assert!(
                in_buffer(e.index) <= rx,
                "line {} moved, but it was sent after the error ({} bytes from line 150)",
                e.index,
                in_buffer(e.index)
            );
        }
    }
    let before = sim.received_lines();
    let next = program_of_many_lengths(100, 5);
    let (etx, _erx, _ctx, crx) = channels();
    let end = link.stream(&next.clone(), 0, etx, crx).await.unwrap();
    assert_eq!(end, StreamEnd::Completed);
    assert_eq!(sim.received_lines(), before + next.len() as u64);
    let last = sim.trace().last().unwrap().clone();
    assert_eq!(last.index, before + next.len() as u64);
    assert_eq!(sim.rx_overflows(), 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_injected_alarm_names_the_line_and_after_unlock_the_next_program_runs() {
    let sim = GrblSim::spawn_pty(GrblSimConfig {
        time_scale: 200.0,
        faults: vec![GrblFault::AlarmAtLine { line: 80, code: 1 }],
        ..Default::default()
    })
    .unwrap();
    let mut link = GrblLink::open(sim.port().to_str().unwrap(), GrblOptions::default())
        .await
        .unwrap();
    let lines = program_of_many_lengths(300, 9);
    let (etx, _erx, _ctx, crx) = channels();
    let err = link.stream(&lines.clone(), 0, etx, crx).await.unwrap_err();
    let LinkError::Alarm { text: msg, .. } = &err else {
        panic!("expected an alarm, got {err}");
    };
    assert!(msg.starts_with("ALARM:1 (Hard limit"), "{msg}");
    assert!(
        msg.ends_with(&format!("while running line 80: {}", lines[79])),
        "{msg}"
    );
    // locked until unlocked
    let next = program_of_many_lengths(50, 1);
    let (etx, _erx, _ctx, crx) = channels();
    match link.stream(&next, 0, etx, crx).await {
        Err(LinkError::Rejected { reason, .. }) => {
            assert!(reason.starts_with("error:9"), "{reason}")
        }
        other => panic!("expected the alarm lock, got {other:?}"),
    }
    link.send_setting("$X").await.unwrap();
    let (etx, _erx, _ctx, crx) = channels();
    assert_eq!(
        link.stream(&next, 0, etx, crx).await.unwrap(),
        StreamEnd::Completed
    );
    assert_eq!(sim.rx_overflows(), 0);
}

#[tokio::test]
async fn opening_a_port_that_does_not_exist_names_the_port() {
    let err = GrblLink::open("/dev/machlink-no-such-port", GrblOptions::default())
        .await
        .err()
        .expect("no such port");
    match &err {
        LinkError::Open { port, .. } => assert_eq!(port, "/dev/machlink-no-such-port"),
        other => panic!("expected an open error, got {other}"),
    }
    assert!(err.to_string().contains("/dev/machlink-no-such-port"));
}
