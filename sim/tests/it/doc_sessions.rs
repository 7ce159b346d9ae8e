//! The protocol documents' example sessions are what the link and the simulated device
//! really exchange: each test runs the session on a tapped in-memory cable under tokio's
//! paused clock (so the times are the line's own, the same on every run) and checks that
//! the document holds the transcript byte for byte.

use machlink_protocols::modbus::frame::{self, Request, Response, Side};
use machlink_protocols::modbus::map::{BlockKind, ModbusState, MotionBlock, Status, WordOrder};
use machlink_protocols::modbus::{ModbusLink, ModbusPost, ModbusSettings};
use machlink_protocols::sewing;
use machlink_protocols::Post;
use machlink_protocols::{Control, Link, StreamEnd};
use machlink_sim::conformance::document_holds;
use machlink_sim::line::{self, hex_lines, Direction, Tap, Tapped};
use machlink_sim::modbus::{Faults, ModbusSim, SimConfig};
use offset_core::{Move, Point, Toolpath, P3};
use std::time::Duration;
use tokio::sync::{mpsc, watch};

/// One line of a transcript: time, direction, bytes (wrapped), meaning.
fn line_of(ms: f64, arrow: &str, bytes: &[u8], meaning: &str) -> String {
    let hex = hex_lines(bytes, 16, 17);
    format!("{ms:8.1}  {arrow}  {hex}\n                 {meaning}\n")
}

fn modbus_request(r: &Request) -> String {
    match r {
        Request::Read { addr, count } => format!("FC3 read {addr}..={}", addr + count - 1),
        Request::Write { addr, words } if words.len() % 16 == 0 && *addr >= 32 => {
            let first = (addr - 32) / 16;
            let n = words.len() as u16 / 16;
            format!(
                "FC16 write {addr}..={}: blocks in slots {first}..={}",
                addr + words.len() as u16 - 1,
                first + n - 1
            )
        }
        Request::Write { addr, words } => format!(
            "FC16 write {addr}..={} = {words:?}",
            addr + words.len() as u16 - 1
        ),
        Request::ReadWrite {
            read_addr,
            read_count,
            write_addr,
            words,
        } => format!(
            "FC23 write {write_addr}..={} = {words:?}, then read {read_addr}..={}",
            write_addr + words.len() as u16 - 1,
            read_addr + read_count - 1
        ),
        other => format!("{other:?}"),
    }
}

fn modbus_reply(r: &Response, order: WordOrder) -> String {
    let header = |v: &[u16]| {
        let s = Status::decode(v, order);
        let state = ModbusState::from_register(s.state).map_or("?", |x| x.name());
        format!(
            "{} registers: version {}, capacity {}, state {state}, write {}, consumed {}",
            v.len(),
            s.version,
            s.capacity,
            s.write_seq,
            s.consumed_seq
        )
    };
    match r {
        Response::Read(v) | Response::ReadWrite(v) if v.len() >= 16 => header(v),
        Response::Write { addr, count } => format!("confirms {count} registers at {addr}"),
        other => format!("{other:?}"),
    }
}

/// The transcript of a Modbus RTU session: requests and replies split into frames.
fn modbus_transcript(
    log: &[Tapped],
    order: WordOrder,
    timeout: Duration,
    quiet: Duration,
) -> String {
    let t0 = log[0].at;
    let mut out = String::new();
    let mut rx: Vec<u8> = Vec::new();
    let mut answered = true;
    for e in log {
        let ms = (e.at - t0).as_secs_f64() * 1e3;
        match e.direction {
            Direction::Sent => {
                if !answered {
                    out.push_str(&format!(
                        "                 (no reply: after the {} ms timeout the link waits for {} ms\n\
                         \x20                of silence, then reads a register count no unanswered\n\
                         \x20                request has)\n",
                        timeout.as_millis(),
                        quiet.as_millis()
                    ));
                }
                let (f, _) = frame::rtu_split(&e.bytes, Side::Request).expect("a whole frame");
                let req = Request::from_pdu(&f.unwrap().pdu).unwrap();
                out.push_str(&line_of(ms, "→", &e.bytes, &modbus_request(&req)));
                answered = false;
            }
            Direction::Received => {
                rx.extend_from_slice(&e.bytes);
                while let Some((f, n)) = frame::rtu_split(&rx, Side::Reply) {
                    let bytes: Vec<u8> = rx.drain(..n).collect();
                    let resp = Response::from_pdu(&f.unwrap().pdu).unwrap();
                    out.push_str(&line_of(ms, "←", &bytes, &modbus_reply(&resp, order)));
                    answered = true;
                }
            }
        }
    }
    out
}

/// docs/modbus.md, "Example session": a two-block job (the worked example's linear move and
/// the end block) at 19200 baud on a ring of 4, whose commit loses its reply.
#[tokio::test(start_paused = true)]
async fn the_modbus_document_shows_the_session_the_link_and_device_have() {
    let blocks = vec![
        MotionBlock {
            kind: BlockKind::Linear,
            target: [12_500, -3_000, -1_000],
            feed: 800_000,
            center: [0, 0],
        },
        MotionBlock {
            kind: BlockKind::End,
            target: [12_500, -3_000, -1_000],
            feed: 0,
            center: [0, 0],
        },
    ];
    let (host, dev) = line::cable(None);
    let (host, log) = Tap::new(host);
    let cfg = SimConfig {
        capacity: 4,
        time_scale: 0.0,
        line_baud: Some(19_200),
        faults: Faults {
            drop_replies: vec![4],
            ..Faults::default()
        },
        ..SimConfig::default()
    };
    let sim = ModbusSim::spawn_rtu_on(cfg, dev);
    let mut s = ModbusSettings::rtu("/dev/ttyUSB0", 19_200);
    s.timeout = Duration::from_millis(100);
    s.rtu_quiet = Duration::from_millis(20);
    s.backoff_initial = Duration::from_millis(10);
    let mut link = ModbusLink::from_stream(host, s).unwrap();
    let (tx, _rx) = mpsc::unbounded_channel();
    let (_ctl, ctl) = watch::channel(Control::Run);
    assert_eq!(
        link.stream(&blocks, 0, tx, ctl).await.unwrap(),
        StreamEnd::Completed
    );
    assert_eq!(sim.trace().len(), 2, "both blocks executed once");
    let text = modbus_transcript(
        &log.lock().unwrap(),
        WordOrder::HighFirst,
        Duration::from_millis(100),
        Duration::from_millis(20),
    );
    document_holds("modbus.md", &text).unwrap();
}

/// docs/modbus.md, "The program as text": what `machlink plan --post modbus` writes.
#[test]
fn the_modbus_document_shows_what_the_post_writes() {
    let mut tp = Toolpath::new("doc");
    tp.push(Move::Rapid {
        to: P3::new(0.0, 0.0, 5.0),
    });
    tp.push(Move::Linear {
        to: P3::new(12.5, -3.0, -1.0),
        feed: 800.0,
    });
    tp.push(Move::Arc {
        to: P3::new(22.5, -3.0, -1.0),
        center: Point::new(17.5, -3.0),
        ccw: false,
        feed: 600.0,
    });
    tp.push(Move::Dwell { seconds: 1.5 });
    tp.push(Move::ToolChange {
        tool: 2,
        name: "6 mm flat end mill".into(),
        geometry: None,
    });
    let blocks = ModbusPost.units(&tp).unwrap();
    let text = String::from_utf8(ModbusPost.file(&blocks, "doc").unwrap()).unwrap();
    document_holds("modbus.md", &text).unwrap();
}

fn sewing_kind(k: u8) -> String {
    use sewing::wire::req;
    match k {
        req::INFO => "INFO".into(),
        req::LOAD_BEGIN => "LOAD_BEGIN".into(),
        req::LOAD_CHUNK => "LOAD_CHUNK".into(),
        req::LOAD_END => "LOAD_END".into(),
        req::START => "START".into(),
        req::STOP => "STOP".into(),
        req::RESUME => "RESUME".into(),
        req::ABORT => "ABORT".into(),
        req::STATUS => "STATUS".into(),
        other => format!("0x{other:02X}"),
    }
}

fn sewing_request(f: &sewing::wire::Frame) -> String {
    use sewing::wire::req;
    let p = &f.payload;
    let u32at = |i: usize| u32::from_le_bytes([p[i], p[i + 1], p[i + 2], p[i + 3]]);
    let what = match f.kind {
        req::INFO => "INFO".to_string(),
        req::STATUS => "STATUS".to_string(),
        req::LOAD_BEGIN => format!("LOAD_BEGIN {} records, CRC-32 {:08X}", u32at(0), u32at(4)),
        req::LOAD_CHUNK => format!(
            "LOAD_CHUNK at {}, {} records",
            u32at(0),
            u16::from_le_bytes([p[4], p[5]])
        ),
        req::LOAD_END => "LOAD_END".to_string(),
        req::START => format!("START at {}, CRC-32 {:08X}", u32at(0), u32at(4)),
        other => format!("request 0x{other:02X}"),
    };
    format!("seq {}: {what}", f.seq)
}

fn sewing_reply(f: &sewing::wire::Frame) -> String {
    use sewing::wire::{reply, req, Info, Status};
    let p = &f.payload;
    let what = match (f.kind, p.first().copied()) {
        (reply::NAK, _) => "NAK: the frame arrived damaged".to_string(),
        (reply::ACK, Some(req::INFO)) => {
            let i = Info::decode(&p[1..]).unwrap();
            format!(
                "ACK INFO: area {}..{} × {}..{} (0.1 mm), longest step {}, {} spm, window {}",
                i.min_x,
                i.max_x,
                i.min_y,
                i.max_y,
                i.max_stitch,
                i.spm,
                i.window()
            )
        }
        (reply::ACK, Some(req::STATUS)) => {
            let s = Status::decode(&p[1..]).unwrap();
            format!(
                "ACK STATUS: {}, counter {}, at ({}, {}), flags {}, pattern {} records CRC-32 {:08X}",
                s.state.name(),
                s.counter,
                s.x,
                s.y,
                s.thread_break as u8 | (s.needle_down as u8) << 1,
                s.pattern_len,
                s.pattern_crc
            )
        }
        (reply::ACK, Some(req::LOAD_CHUNK)) => format!(
            "ACK LOAD_CHUNK: {} records loaded",
            u32::from_le_bytes([p[1], p[2], p[3], p[4]])
        ),
        (reply::ACK, Some(k)) => format!("ACK {} (no data)", sewing_kind(k)),
        (reply::REFUSED, Some(k)) => format!("REFUSED {}, code {}", sewing_kind(k), p[1]),
        _ => format!("{f:?}"),
    };
    format!("seq {}: {what}", f.seq)
}

/// The transcript of a sewing session: frames each way.
fn sewing_transcript(log: &[Tapped]) -> String {
    use sewing::wire::{Decoded, Decoder};
    let t0 = log[0].at;
    let mut out = String::new();
    let (mut tx, mut rx) = (Decoder::default(), Decoder::default());
    for e in log {
        let ms = (e.at - t0).as_secs_f64() * 1e3;
        let (dec, arrow, sent) = match e.direction {
            Direction::Sent => (&mut tx, "→", true),
            Direction::Received => (&mut rx, "←", false),
        };
        dec.push(&e.bytes);
        let mut frames = Vec::new();
        while let Some(d) = dec.next_frame() {
            frames.push(d);
        }
        for d in frames {
            let (bytes, meaning) = match d {
                Decoded::Frame(f) => (
                    f.encode(),
                    if sent { sewing_request(&f) } else { sewing_reply(&f) },
                ),
                Decoded::Corrupt { seq } => (
                    e.bytes.clone(),
                    format!("seq {seq}: a LOAD_CHUNK with bit 4 of byte 12 flipped on the line (its CRC fails)"),
                ),
            };
            out.push_str(&line_of(ms, arrow, &bytes, &meaning));
        }
    }
    out
}

/// docs/sewing-link.md, "Example session": a three-record pattern sewn by a machine of
/// protocol version 2 at 115200 baud, whose first chunk is damaged on the line.
#[tokio::test(start_paused = true)]
async fn the_sewing_document_shows_the_session_the_link_and_machine_have() {
    use machlink_protocols::sewing::link::{SewingLink, SewingTiming};
    use machlink_protocols::sewing::{StitchKind, StitchRecord};
    use machlink_sim::sewing::{spawn_on, SewingSimConfig, Trace};
    let pattern = vec![
        StitchRecord::new(StitchKind::Stitch, 0, 0),
        StitchRecord::new(StitchKind::Stitch, 20, 0),
        StitchRecord::new(StitchKind::Stitch, 20, 15),
    ];
    let (host, dev) = line::cable(None);
    let (host, log) = Tap::new(host);
    // the link's fourth write is the first LOAD_CHUNK: bit 4 of its byte 12 flips
    let host = host.flipping(4, 12, 0x10);
    let trace = Trace::default();
    let cfg = SewingSimConfig {
        baud: Some(115_200),
        time_scale: 100.0,
        ..SewingSimConfig::default()
    };
    let _machine = spawn_on(dev, cfg, trace.clone());
    let mut link = SewingLink::new(host, SewingTiming::default());
    let (tx, _rx) = mpsc::unbounded_channel();
    let (_ctl, ctl) = watch::channel(Control::Run);
    assert_eq!(
        link.stream(&pattern, 0, tx, ctl).await.unwrap(),
        StreamEnd::Completed
    );
    assert_eq!(
        trace.lock().unwrap().drops.len(),
        3,
        "every stitch sewn once"
    );
    let text = sewing_transcript(&log.lock().unwrap());
    document_holds("sewing-link.md", &text).unwrap();
}

/// The transcript of a GRBL session: lines (and real-time bytes) each way.
fn grbl_transcript(log: &[Tapped]) -> String {
    let t0 = log[0].at;
    let mut out = String::new();
    let mut rx = String::new();
    for e in log {
        let ms = (e.at - t0).as_secs_f64() * 1e3;
        match e.direction {
            Direction::Sent => {
                let mut line = String::new();
                for &b in &e.bytes {
                    match b {
                        b'\n' => {
                            out.push_str(&format!("{ms:8.1}  →  {line}\n"));
                            line.clear();
                        }
                        b'?' | b'!' | b'~' if line.is_empty() => {
                            out.push_str(&format!("{ms:8.1}  →  {}   (real time)\n", b as char))
                        }
                        0x18 => {
                            out.push_str(&format!("{ms:8.1}  →  0x18 (real time: soft reset)\n"))
                        }
                        b => line.push(b as char),
                    }
                }
            }
            Direction::Received => {
                rx.push_str(&String::from_utf8_lossy(&e.bytes));
                while let Some(i) = rx.find("\r\n") {
                    let line: String = rx.drain(..i + 2).collect();
                    let line = line.trim_end();
                    if !line.is_empty() {
                        out.push_str(&format!("{ms:8.1}  ←  {line}\n"));
                    }
                }
            }
        }
    }
    out
}

/// docs/grbl.md, "Example session": a short program whose fifth line GRBL refuses, and the
/// resume after it.
#[tokio::test(start_paused = true)]
async fn the_grbl_document_shows_the_session_the_link_and_controller_have() {
    use machlink_protocols::grbl::{GrblLink, GrblOptions};
    use machlink_protocols::LinkError;
    use machlink_sim::grbl::{GrblFault, GrblSim, GrblSimConfig};
    let program: Vec<String> = [
        "G21 G90 G17 G94",
        "G0 Z5",
        "G0 X0 Y0",
        "G1 Z-1 F300",
        "G1 X10 F600",
        "G1 Y10",
        "G1 X0",
        "G0 Z5",
        "M2",
    ]
    .map(String::from)
    .to_vec();
    let (host, dev) = line::cable(None);
    let (host, log) = Tap::new(host);
    let sim = GrblSim::spawn_on(
        dev,
        GrblSimConfig {
            time_scale: 50.0,
            faults: vec![GrblFault::ErrorAtLine { line: 5, code: 20 }],
            ..GrblSimConfig::default()
        },
    )
    .unwrap();
    let mut link = GrblLink::from_stream(host, GrblOptions::default())
        .await
        .unwrap();
    let (tx, mut rx) = mpsc::unbounded_channel();
    let (_ctl, ctl) = watch::channel(Control::Run);
    let e = link
        .stream(&program, 0, tx.clone(), ctl.clone())
        .await
        .unwrap_err();
    let LinkError::Rejected { unit, .. } = e else {
        panic!("{e}")
    };
    assert_eq!(unit, 4, "the fifth line is refused");
    while rx.try_recv().is_ok() {}
    // GRBL had planned lines 1 to 4 (and said ok) but the reset dropped them unexecuted:
    // the operator runs the job again from its start
    assert!(sim.trace().is_empty(), "nothing ran before the reset");
    assert_eq!(
        link.stream(&program, 0, tx, ctl).await.unwrap(),
        StreamEnd::Completed
    );
    assert_eq!(sim.trace().len(), 7, "every move of the job ran once");
    let text = grbl_transcript(&log.lock().unwrap());
    document_holds("grbl.md", &text).unwrap();
}
