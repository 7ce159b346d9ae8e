//! Tests of the GRBL link against a fake controller on an in-memory pipe that acknowledges
//! late, at random, and pushes unsolicited messages between acknowledgements.

use super::*;
use std::sync::{Arc, Mutex};
use tokio::io::DuplexStream;

/// A tiny deterministic random source (xorshift64*).
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
}

#[derive(Clone, Default)]
struct FakeConfig {
    /// What `$I` reports as the receive buffer; None leaves `[OPT:…]` out.
    window: Option<usize>,
    seed: u64,
    /// 1-based G-code line that gets `error:N`.
    error_at: Option<(usize, u16)>,
    /// 1-based G-code line that raises `ALARM:N`.
    alarm_at: Option<(usize, u16)>,
    /// Status reports that still say Run once every line is answered (the last moves).
    run_after: usize,
    /// Status reports after a cycle start (`~`) that still say Hold, as GRBL's does when the
    /// `?` is taken in the same turn of its loop as the `~`, or was sent before it.
    holds_after_resume: usize,
}

#[derive(Default)]
struct FakeLog {
    /// The most bytes ever received and not yet acknowledged.
    max_in_flight: usize,
    /// Every non-`$` line received, in order.
    gcode: Vec<String>,
    /// Every real-time byte received, in order.
    realtime: Vec<u8>,
    resets: usize,
}

async fn fake_controller(io: DuplexStream, cfg: FakeConfig, log: Arc<Mutex<FakeLog>>) {
    let (mut r, mut w) = tokio::io::split(io);
    let mut rng = Rng(cfg.seed | 1);
    let window = cfg.window.unwrap_or(DEFAULT_WINDOW);
    let banner = b"\r\nGrbl 1.1h ['$' for help]\r\n".to_vec();
    let _ = w.write_all(&banner).await;
    let mut partial: Vec<u8> = Vec::new();
    let mut pending: VecDeque<(String, usize)> = VecDeque::new();
    let mut in_flight = 0usize;
    let mut gcode_count = 0usize;
    let mut locked = false;
    let mut held = false;
    let mut run_after = cfg.run_after;
    let mut stale_holds = 0usize;
    let mut buf = [0u8; 256];
    loop {
        let mut out: Vec<u8> = Vec::new();
        let wait = Duration::from_micros(200 + rng.below(3000));
        tokio::select! {
            got = r.read(&mut buf) => {
                let n = match got { Ok(0) | Err(_) => return, Ok(n) => n };
                for &b in &buf[..n] {
                    if realtime::is_realtime(b) {
                        log.lock().unwrap().realtime.push(b);
                        match b {
                            b'?' => {
                                let busy = !pending.is_empty() || run_after > 0;
                                if pending.is_empty() && run_after > 0 && gcode_count > 0 {
                                    run_after -= 1;
                                }
                                let stale = stale_holds > 0;
                                stale_holds = stale_holds.saturating_sub(1);
                                let state = if held || stale { "Hold:0" } else if locked { "Alarm" } else if busy { "Run" } else { "Idle" };
                                out.extend(format!("<{state}|MPos:0.000,0.000,0.000|Bf:{},{}|FS:0,0>\r\n", 15 - pending.len().min(15), window.saturating_sub(in_flight)).as_bytes());
                            }
                            b'!' => held = true,
                            b'~' => {
                                if held {
                                    stale_holds = cfg.holds_after_resume;
                                }
                                held = false;
                            }
                            0x18 => {
                                partial.clear();
                                pending.clear();
                                in_flight = 0;
                                held = false;
                                log.lock().unwrap().resets += 1;
                                out.extend(&banner);
                            }
                            _ => {}
                        }
                        continue;
                    }
                    in_flight += 1;
                    let mut l = log.lock().unwrap();
                    l.max_in_flight = l.max_in_flight.max(in_flight);
                    drop(l);
                    if b == b'\n' {
                        let text = String::from_utf8_lossy(&partial).into_owned();
                        pending.push_back((text, partial.len() + 1));
                        partial.clear();
                    } else {
                        partial.push(b);
                    }
                }
            }
            _ = tokio::time::sleep(wait) => {
                // acknowledge 0..=3 of the oldest lines, and now and then push a message
                if rng.below(5) == 0 {
                    let state = if held { "Hold:0" } else if pending.is_empty() && run_after == 0 { "Idle" } else { "Run" };
                    out.extend(format!("[MSG:Pgm End]\r\n<{state}|MPos:1.000,2.000,3.000|FS:100,0>\r\n").as_bytes());
                }
                for _ in 0..rng.below(4) {
                    // a held controller runs nothing on, so answers nothing more
                    if held {
                        break;
                    }
                    if locked && !pending.front().is_some_and(|(l, _)| l.starts_with('$')) {
                        break;
                    }
                    let Some((line, len)) = pending.pop_front() else { break };
                    in_flight -= len;
                    if line == "$I" {
                        out.extend(b"[VER:1.1h.20190825:]\r\n");
                        if let Some(wnd) = cfg.window {
                            out.extend(format!("[OPT:V,15,{wnd}]\r\n").as_bytes());
                        }
                        out.extend(b"ok\r\n");
                    } else if line.starts_with('$') {
                        if line == "$X" { locked = false; }
                        out.extend(b"ok\r\n");
                    } else {
                        gcode_count += 1;
                        // a program stop: the controller holds once it reaches it
                        held |= line.starts_with("M0");
                        log.lock().unwrap().gcode.push(line);
                        if cfg.error_at.is_some_and(|(k, _)| k == gcode_count) {
                            out.extend(format!("error:{}\r\n", cfg.error_at.unwrap().1).as_bytes());
                        } else if cfg.alarm_at.is_some_and(|(k, _)| k == gcode_count) {
                            out.extend(format!("ALARM:{}\r\n[MSG:Reset to continue]\r\n", cfg.alarm_at.unwrap().1).as_bytes());
                            locked = true;
                        } else if locked {
                            out.extend(b"error:9\r\n");
                        } else {
                            out.extend(b"ok\r\n");
                        }
                    }
                }
            }
        }
        if !out.is_empty() && w.write_all(&out).await.is_err() {
            return;
        }
    }
}

async fn connect(cfg: FakeConfig) -> (GrblLink, Arc<Mutex<FakeLog>>) {
    let (a, b) = tokio::io::duplex(4096);
    let log = Arc::new(Mutex::new(FakeLog::default()));
    tokio::spawn(fake_controller(b, cfg, log.clone()));
    let link = GrblLink::from_stream(a, GrblOptions::default())
        .await
        .expect("the fake controller greets and answers $I");
    (link, log)
}

/// Lines of every length from 3 to `max` bytes, in a shuffled order.
fn lines_of_many_lengths(count: usize, max: usize, seed: u64) -> Vec<String> {
    let mut rng = Rng(seed | 1);
    (0..count)
        .map(|i| {
            let len = 3 + rng.below((max - 2) as u64) as usize;
            let mut l = format!("G1X{i}");
            while l.len() < len {
                l.push('0');
            }
            l.truncate(len.max(3));
            l
        })
        .collect()
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

fn acked_units(erx: &mut mpsc::UnboundedReceiver<LinkEvent>) -> Vec<usize> {
    let mut v = Vec::new();
    while let Ok(e) = erx.try_recv() {
        if let LinkEvent::Acked { unit } = e {
            v.push(unit);
        }
    }
    v
}

#[tokio::test(start_paused = true)]
async fn bytes_in_flight_never_exceed_the_window() {
    for (window, seed) in [(Some(128), 7), (Some(48), 11), (None, 13)] {
        let (mut link, log) = connect(FakeConfig {
            window,
            seed,
            ..Default::default()
        })
        .await;
        let w = window.unwrap_or(DEFAULT_WINDOW);
        assert_eq!(link.window(), w);
        let lines = lines_of_many_lengths(2500, w - 1, seed);
        let program = lines.clone();
        let (etx, mut erx, _ctx, crx) = channels();
        let end = link.stream(&program, 0, etx, crx).await.unwrap();
        assert_eq!(end, StreamEnd::Completed);
        let log = log.lock().unwrap();
        assert!(
            log.max_in_flight <= w,
            "{} bytes in flight with a {w}-byte window",
            log.max_in_flight
        );
        // the window was actually used, not one line at a time
        assert!(log.max_in_flight > w / 2, "{}", log.max_in_flight);
        assert_eq!(log.gcode, lines, "every line arrived once, in order");
        assert_eq!(acked_units(&mut erx), (0..lines.len()).collect::<Vec<_>>());
        assert!(log.realtime.contains(&b'?'));
    }
}

#[tokio::test(start_paused = true)]
async fn an_error_stops_the_stream_naming_the_line_and_the_link_stays_usable() {
    let (mut link, log) = connect(FakeConfig {
        window: Some(128),
        seed: 3,
        error_at: Some((40, 20)),
        ..Default::default()
    })
    .await;
    let lines = lines_of_many_lengths(200, 60, 5);
    let program = lines.clone();
    let (etx, mut erx, _ctx, crx) = channels();
    let err = link.stream(&program, 0, etx, crx).await.unwrap_err();
    match &err {
        LinkError::Rejected { unit, text, reason } => {
            assert_eq!(*unit, 39);
            assert_eq!(text, &lines[39]);
            assert!(
                reason.starts_with("error:20 (Unsupported command"),
                "{reason}"
            );
        }
        other => panic!("expected a rejection, got {other}"),
    }
    // nothing after the rejected line was reported as done
    assert!(acked_units(&mut erx).iter().all(|&u| u < 39));
    {
        let l = log.lock().unwrap();
        let hold = l.realtime.iter().position(|&b| b == b'!').unwrap();
        let reset = l.realtime.iter().position(|&b| b == 0x18).unwrap();
        assert!(hold < reset, "a feed hold comes before the reset");
        assert_eq!(l.resets, 1);
    }
    // the same link runs the next program
    let next = lines_of_many_lengths(30, 60, 9);
    let (etx, _erx, _ctx, crx) = channels();
    assert_eq!(
        link.stream(&next, 0, etx, crx).await.unwrap(),
        StreamEnd::Completed
    );
}

#[tokio::test(start_paused = true)]
async fn an_alarm_stops_the_stream_and_after_unlock_the_next_program_runs() {
    let (mut link, log) = connect(FakeConfig {
        window: Some(128),
        seed: 21,
        alarm_at: Some((25, 1)),
        ..Default::default()
    })
    .await;
    let lines = lines_of_many_lengths(100, 40, 2);
    let program = lines.clone();
    let (etx, _erx, _ctx, crx) = channels();
    let err = link.stream(&program, 0, etx, crx).await.unwrap_err();
    let LinkError::Alarm {
        code: Some(1),
        text: msg,
    } = &err
    else {
        panic!("expected alarm 1, got {err}");
    };
    assert!(msg.starts_with("ALARM:1 (Hard limit"), "{msg}");
    assert!(
        msg.ends_with(&format!("while running line 25: {}", lines[24])),
        "{msg}"
    );
    assert_eq!(log.lock().unwrap().resets, 1);
    link.send_setting("$X").await.unwrap();
    let (etx, _erx, _ctx, crx) = channels();
    let next = lines_of_many_lengths(20, 40, 4);
    assert_eq!(
        link.stream(&next, 0, etx, crx).await.unwrap(),
        StreamEnd::Completed
    );
}

#[tokio::test(start_paused = true)]
async fn resume_skips_acknowledged_lines_and_repositions_first() {
    let (mut link, log) = connect(FakeConfig {
        window: Some(128),
        seed: 5,
        ..Default::default()
    })
    .await;
    let mut lines = vec![
        "G21 G90".to_string(),
        "G0 X0 Y0 Z1".to_string(),
        "M3 S1000".to_string(),
        "G1 Z-1 F100".to_string(),
        "G1 X1 F300".to_string(),
    ];
    lines.extend(lines_of_many_lengths(300, 50, 8));
    let program = lines.clone();
    let (etx, mut erx, _ctx, crx) = channels();
    let end = link.stream(&program, 120, etx, crx).await.unwrap();
    assert_eq!(end, StreamEnd::Completed);
    let l = log.lock().unwrap();
    let back = resume::reposition(&lines, 120, &resume::ResumeOptions::default()).unwrap();
    let sent: Vec<String> = back
        .lines
        .iter()
        .map(|(l, _)| format!("{l} (resume)"))
        .collect();
    assert_eq!(sent[0], "G21 G90 G17 G54 G94 (resume)");
    assert_eq!(sent[1], "G0 Z1.000 (resume)");
    assert_eq!(sent[2], "M3 S1000 (resume)");
    assert!(
        sent.iter().any(|l| l == "G1 Z-1.000 F100 (resume)"),
        "{sent:?}"
    );
    assert_eq!(l.gcode[..sent.len()], sent[..]);
    assert_eq!(l.gcode[sent.len()..], lines[120..]);
    assert_eq!(
        acked_units(&mut erx),
        (120..lines.len()).collect::<Vec<_>>()
    );
}

#[tokio::test(start_paused = true)]
async fn cancel_holds_then_resets_and_reports_what_was_acknowledged() {
    let (mut link, log) = connect(FakeConfig {
        window: Some(128),
        seed: 17,
        ..Default::default()
    })
    .await;
    let program = lines_of_many_lengths(5000, 60, 1);
    let (etx, mut erx, ctx, crx) = channels();
    let canceller = tokio::spawn(async move {
        tokio::time::sleep(Duration::from_millis(300)).await;
        ctx.send(Control::Hold).unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        ctx.send(Control::Run).unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        ctx.send(Control::Cancel).unwrap();
        ctx
    });
    let end = link.stream(&program, 0, etx, crx).await.unwrap();
    let _ctx = canceller.await.unwrap();
    let StreamEnd::Cancelled { acked } = end else {
        panic!("expected a cancel, got {end:?}");
    };
    let units = acked_units(&mut erx);
    assert_eq!(units.len(), acked);
    assert!(acked > 0 && acked < 5000, "{acked}");
    let l = log.lock().unwrap();
    let rt: Vec<u8> = l.realtime.iter().copied().filter(|&b| b != b'?').collect();
    assert_eq!(rt, vec![b'!', b'~', b'!', 0x18]);
}

#[tokio::test(start_paused = true)]
async fn lines_grbl_would_misread_are_refused_before_anything_is_sent() {
    let (mut link, log) = connect(FakeConfig {
        window: Some(64),
        seed: 1,
        ..Default::default()
    })
    .await;
    for bad in ["G1 X1 (why?)", &"G1 X1".repeat(20)] {
        let program = vec!["G0 X0".into(), bad.to_string()];
        let (etx, _erx, _ctx, crx) = channels();
        match link.stream(&program, 0, etx, crx).await {
            Err(LinkError::Rejected { unit: 1, .. }) => {}
            other => panic!("expected a refusal of line 2, got {other:?}"),
        }
    }
    assert!(log.lock().unwrap().gcode.is_empty());
}

#[tokio::test(start_paused = true)]
async fn completion_waits_for_idle_polling_at_most_five_times_a_second() {
    let (mut link, log) = connect(FakeConfig {
        window: Some(128),
        seed: 23,
        run_after: 20,
        ..Default::default()
    })
    .await;
    let program = lines_of_many_lengths(50, 40, 3);
    let (etx, mut erx, _ctx, crx) = channels();
    let start = Instant::now();
    let end = link.stream(&program, 0, etx, crx).await.unwrap();
    let elapsed = start.elapsed().as_secs_f64();
    assert_eq!(end, StreamEnd::Completed);
    let polls = log
        .lock()
        .unwrap()
        .realtime
        .iter()
        .filter(|&&b| b == b'?')
        .count();
    // 20 reports said Run after the last ok: the stream waited for Idle ...
    assert!(polls >= 21, "{polls} polls");
    // ... without polling faster than 5 Hz (plus the early poll at the last ok, and the
    // one that greets the controller when connecting)
    assert!(
        polls as f64 <= elapsed * 5.0 + 3.0,
        "{polls} polls in {elapsed:.2} s"
    );
    let statuses = std::iter::from_fn(|| erx.try_recv().ok())
        .filter(|e| matches!(e, LinkEvent::Status(_)))
        .count();
    assert!(statuses >= 21);
}

#[tokio::test(start_paused = true)]
async fn a_status_report_made_before_the_cycle_start_does_not_pause_the_job_again() {
    // The controller holds at each M0, and after the operator's cycle start its next report
    // still says Hold (made in the same turn of its loop as the `~`). Taken as a new pause,
    // that report made the daemon hold the job again at the stop it had just left.
    let (mut link, log) = connect(FakeConfig {
        window: Some(128),
        seed: 23,
        holds_after_resume: 1,
        ..Default::default()
    })
    .await;
    let mut program = lines_of_many_lengths(600, 60, 5);
    program[200] = "M0 (load T2)".into();
    program[400] = "M0 (load T3)".into();
    let (etx, mut erx, ctx, crx) = channels();
    // the operator, as the daemon is: each time the machine pauses itself, hold the job,
    // then resume it a little later
    let operator = tokio::spawn(async move {
        let mut pauses = 0;
        let mut acked = Vec::new();
        while let Some(e) = erx.recv().await {
            match e {
                LinkEvent::Message(m) if m.contains("paused itself") => {
                    pauses += 1;
                    ctx.send(Control::Hold).unwrap();
                    tokio::time::sleep(Duration::from_millis(300)).await;
                    ctx.send(Control::Run).unwrap();
                }
                LinkEvent::Acked { unit } => acked.push(unit),
                _ => {}
            }
        }
        (pauses, acked)
    });
    let end = link.stream(&program, 0, etx, crx).await.unwrap();
    assert_eq!(end, StreamEnd::Completed);
    drop(link);
    let (pauses, acked) = operator.await.unwrap();
    assert_eq!(pauses, 2, "one pause per program stop");
    assert_eq!(acked, (0..program.len()).collect::<Vec<_>>());
    let l = log.lock().unwrap();
    assert_eq!(l.gcode, program, "every line arrived once, in order");
    let rt: Vec<u8> = l.realtime.iter().copied().filter(|&b| b != b'?').collect();
    assert_eq!(
        rt,
        vec![b'!', b'~', b'!', b'~'],
        "one hold and one resume per stop"
    );
}
