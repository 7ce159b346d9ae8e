//! The protocol documents' example sessions are what the link and the simulated device
//! really exchange: each test runs the session on a tapped in-memory cable under tokio's
//! paused clock (so the times are the line's own, the same on every run) and checks that
//! the document holds the transcript byte for byte.

use machlink_protocols::modbus::frame::{self, Request, Response, Side};
use machlink_protocols::modbus::map::{BlockKind, ModbusState, MotionBlock, Status, WordOrder};
use machlink_protocols::modbus::{ModbusLink, ModbusPost, ModbusSettings};
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
    let blocks = ModbusPost.units(&tp).unwrap();
    let text = String::from_utf8(ModbusPost.file(&blocks, "doc").unwrap()).unwrap();
    document_holds("modbus.md", &text).unwrap();
}
