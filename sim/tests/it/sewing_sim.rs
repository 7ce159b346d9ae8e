//! The sewing link against the simulated pattern sewing machine over a pty: every planned
//! stitch sewn exactly once, in order, through line noise, a thread break, a power loss, a
//! cancel and a resume; corrupt or repeated packets never sew a wrong stitch.

use machlink_protocols::sewing::link::{Reply, SewingLink, SewingTiming};
use machlink_protocols::sewing::wire::{self, req, Decoded, Decoder, Frame};
use machlink_protocols::sewing::{pattern_crc, records, RecordLimits, StitchKind, StitchRecord};
use machlink_protocols::{Control, Link, LinkError, LinkEvent, StreamEnd};
use machlink_sim::sewing::{spawn_on_pty, SewingSim, SewingSimConfig};
use offset_core::geom::{Point, Polyline, Shape};
use offset_core::stitch::{stitch, StitchParams};
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::{mpsc, watch};

/// A jeans back pocket (120 × 90 mm with a pointed bottom) and a small label, sewn on the line.
fn pattern() -> Vec<StitchRecord> {
    let pocket = Polyline::from_points(
        &[
            Point::new(-60.0, 40.0),
            Point::new(-60.0, -30.0),
            Point::new(0.0, -50.0),
            Point::new(60.0, -30.0),
            Point::new(60.0, 40.0),
        ],
        false,
    );
    let label = Polyline::rect(Point::new(-20.0, 0.0), Point::new(20.0, 20.0));
    let p = StitchParams {
        stitch_length: 1.5,
        tie: true,
        ..Default::default()
    };
    let tp = stitch(&Shape::new(vec![pocket, label]), &p).unwrap();
    records(&tp, RecordLimits::DST).unwrap()
}

fn fast(cfg: SewingSimConfig) -> SewingSimConfig {
    SewingSimConfig {
        spm: 3000,
        time_scale: 20.0, // 1 ms per stitch
        ..cfg
    }
}

fn timing() -> SewingTiming {
    SewingTiming {
        reply_timeout: Duration::from_millis(80),
        attempts: 60,
        poll: Duration::from_millis(15),
        idle_gap: Duration::from_millis(25),
    }
}

/// The (index, x, y) of every needle drop the program asks for, in order.
fn planned_drops(recs: &[StitchRecord]) -> Vec<(u32, i32, i32)> {
    recs.iter()
        .enumerate()
        .filter(|(_, r)| r.kind == StitchKind::Stitch)
        .map(|(i, r)| (i as u32, r.x, r.y))
        .collect()
}

fn sewn_drops(sim: &SewingSim) -> Vec<(u32, i32, i32)> {
    let t = sim.trace.lock().unwrap();
    t.drops.iter().map(|d| (d.index, d.x, d.y)).collect()
}

/// Streams `program` from `from`, resuming whenever the machine reports a thread break, and
/// returning the end and the highest unit acknowledged.
async fn stream_resuming_breaks(
    link: &mut SewingLink,
    program: &[StitchRecord],
    from: usize,
    cancel_after: Option<usize>,
) -> (Result<StreamEnd, LinkError>, Option<usize>, Vec<String>) {
    let (etx, mut erx) = mpsc::unbounded_channel();
    let (ctx, crx) = watch::channel(Control::Run);
    let operator = tokio::spawn(async move {
        let mut acked = None;
        let mut messages = vec![];
        let mut held = false;
        while let Some(e) = erx.recv().await {
            match e {
                LinkEvent::Acked { unit } => {
                    assert!(acked.is_none_or(|a| unit > a), "acks go forward");
                    acked = Some(unit);
                    if let Some(c) = cancel_after {
                        if unit >= c {
                            let _ = ctx.send(Control::Cancel);
                        }
                    }
                    // a hold and a run once along the way
                    if unit >= 40 && !held {
                        held = true;
                        let _ = ctx.send(Control::Hold);
                        tokio::time::sleep(Duration::from_millis(30)).await;
                        let _ = ctx.send(Control::Run);
                    }
                }
                LinkEvent::Message(m) => {
                    if m.contains("thread break") {
                        // the operator rethreads and resumes, or, in a job to be
                        // cancelled, cancels there (the break stops the machine, so the
                        // cancel cannot arrive after the last stitch however late the
                        // operator is scheduled)
                        let next = if cancel_after.is_some() {
                            Control::Cancel
                        } else {
                            Control::Run
                        };
                        let _ = ctx.send(next);
                    }
                    messages.push(m);
                }
                LinkEvent::Status(_) => {}
            }
        }
        (acked, messages)
    });
    let end = link.stream(program, from, etx, crx).await;
    let (acked, messages) = operator.await.unwrap();
    (end, acked, messages)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn noise_and_a_thread_break_sew_every_stitch_once_in_order() {
    let recs = pattern();
    assert!(recs.len() > 250, "{}", recs.len());
    let sim = spawn_on_pty(fast(SewingSimConfig {
        noise: 0.003,
        seed: 7,
        thread_break_at: vec![150],
        ..Default::default()
    }))
    .unwrap();
    let mut link = SewingLink::open(&sim.path, 115_200, timing()).unwrap();
    let program = recs.clone();
    let (end, acked, messages) = stream_resuming_breaks(&mut link, &program, 0, None).await;
    assert_eq!(end.unwrap(), StreamEnd::Completed);
    assert_eq!(acked, Some(recs.len() - 1));
    assert_eq!(sewn_drops(&sim), planned_drops(&recs));
    assert!(messages
        .iter()
        .any(|m| m.contains("thread break at stitch 150")));
    let t = sim.trace.lock().unwrap();
    assert!(
        t.events.iter().any(|e| e == "thread break at 150"),
        "{:?}",
        t.events
    );
    assert!(
        link.retransmissions > 0 && t.corrupt_frames + t.duplicates > 0,
        "the noise never hit: {} retransmissions",
        link.retransmissions
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_power_loss_uploads_the_pattern_again_and_sews_on_from_the_counter() {
    let recs = pattern();
    let sim = spawn_on_pty(fast(SewingSimConfig {
        noise: 0.001,
        seed: 3,
        power_loss_at: vec![200],
        ..Default::default()
    }))
    .unwrap();
    let mut link = SewingLink::open(&sim.path, 115_200, timing()).unwrap();
    let program = recs.clone();
    let (end, _, messages) = stream_resuming_breaks(&mut link, &program, 0, None).await;
    assert_eq!(end.unwrap(), StreamEnd::Completed);
    assert_eq!(sewn_drops(&sim), planned_drops(&recs));
    assert!(messages.iter().any(|m| m.contains("lost its pattern")));
    // the next piece of the batch: the same pattern, a new job from 0, sewn whole again
    // without another upload
    let (end, _, _) = stream_resuming_breaks(&mut link, &program, 0, None).await;
    assert_eq!(end.unwrap(), StreamEnd::Completed);
    let twice: Vec<_> = planned_drops(&recs)
        .into_iter()
        .chain(planned_drops(&recs))
        .collect();
    assert_eq!(sewn_drops(&sim), twice);
    let t = sim.trace.lock().unwrap();
    let verified = t
        .events
        .iter()
        .filter(|e| e.starts_with("pattern verified"))
        .count();
    assert_eq!(verified, 2, "{:?}", t.events);
    assert!(
        t.events.iter().any(|e| e == "start at 200"),
        "{:?}",
        t.events
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cancel_then_resume_from_the_last_acknowledged_stitch() {
    let recs = pattern();
    // The cancel goes out once stitch 100 is acknowledged; a thread break at 130 stops the
    // machine in case it comes late (a loaded machine sews the rest before the operator
    // task runs), and the operator cancels there instead.
    let sim = spawn_on_pty(fast(SewingSimConfig {
        thread_break_at: vec![130],
        ..SewingSimConfig::default()
    }))
    .unwrap();
    let mut link = SewingLink::open(&sim.path, 115_200, timing()).unwrap();
    let program = recs.clone();
    let (end, _, _) = stream_resuming_breaks(&mut link, &program, 0, Some(100)).await;
    let acked = match end.unwrap() {
        StreamEnd::Cancelled { acked } => acked,
        other => panic!("{other:?}"),
    };
    assert!(acked >= 100 && acked < recs.len(), "{acked}");
    // nothing past the acknowledged point was sewn
    let so_far = sewn_drops(&sim);
    assert!(so_far.iter().all(|(i, _, _)| (*i as usize) < acked));
    // resume from there: the machine still holds the pattern, so nothing is uploaded again
    let (end, _, _) = stream_resuming_breaks(&mut link, &program, acked, None).await;
    assert_eq!(end.unwrap(), StreamEnd::Completed);
    assert_eq!(sewn_drops(&sim), planned_drops(&recs));
    let t = sim.trace.lock().unwrap();
    assert_eq!(
        t.events
            .iter()
            .filter(|e| e.starts_with("pattern verified"))
            .count(),
        1
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stitch_outside_the_sewing_area_is_refused_before_anything_is_sent() {
    let mut recs = pattern();
    let k = recs.len() / 2;
    recs.insert(k, StitchRecord::new(StitchKind::Jump, 1600, 0));
    let sim = spawn_on_pty(fast(SewingSimConfig::default())).unwrap();
    let mut link = SewingLink::open(&sim.path, 115_200, timing()).unwrap();
    let (etx, _erx) = mpsc::unbounded_channel();
    let (_ctx, crx) = watch::channel(Control::Run);
    let err = link.stream(&recs, 0, etx, crx).await.unwrap_err();
    match &err {
        LinkError::Rejected { unit, text, .. } => {
            assert_eq!(*unit, k);
            assert!(text.contains("(160.0, 0.0)"), "{text}");
        }
        other => panic!("{other}"),
    }
    let st = link.status().await.unwrap();
    assert_eq!(st.state, wire::SewingState::NoPattern);
    assert!(sim.trace.lock().unwrap().events.is_empty());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_machine_sews_nothing_it_has_not_verified() {
    let recs = pattern();
    let sim = spawn_on_pty(fast(SewingSimConfig::default())).unwrap();
    let mut link = SewingLink::open(&sim.path, 115_200, timing()).unwrap();
    let crc = pattern_crc(&recs);
    let start = |at: u32, crc: u32| {
        let mut p = at.to_le_bytes().to_vec();
        p.extend_from_slice(&crc.to_le_bytes());
        p
    };
    // no pattern yet
    let r = link.request(req::START, start(0, crc)).await.unwrap();
    assert!(matches!(r, Reply::Refused { code, .. } if code == wire::refusal::NO_PATTERN));
    // a pattern whose CRC does not match its records (one record altered in transit)
    let mut begin = (recs.len() as u32).to_le_bytes().to_vec();
    begin.extend_from_slice(&crc.to_le_bytes());
    assert_eq!(
        link.request(req::LOAD_BEGIN, begin).await.unwrap(),
        Reply::Ack(vec![])
    );
    let mut tampered = recs.clone();
    tampered[10].x += 1;
    for (k, chunk) in tampered.chunks(wire::CHUNK_RECORDS).enumerate() {
        let mut p = ((k * wire::CHUNK_RECORDS) as u32).to_le_bytes().to_vec();
        p.extend_from_slice(&(chunk.len() as u16).to_le_bytes());
        chunk.iter().for_each(|r| p.extend_from_slice(&r.to_wire()));
        // the acknowledgement carries the records loaded so far (protocol version 2)
        let loaded = (k * wire::CHUNK_RECORDS + chunk.len()) as u32;
        assert_eq!(
            link.request(req::LOAD_CHUNK, p).await.unwrap(),
            Reply::Ack(loaded.to_le_bytes().to_vec())
        );
    }
    let r = link.request(req::LOAD_END, vec![]).await.unwrap();
    assert!(
        matches!(&r, Reply::Refused { code, text } if *code == wire::refusal::PATTERN_INVALID && text.contains("CRC")),
        "{r:?}"
    );
    let r = link.request(req::START, start(0, crc)).await.unwrap();
    assert!(matches!(r, Reply::Refused { .. }), "{r:?}");
    tokio::time::sleep(Duration::from_millis(50)).await;
    assert!(sewn_drops(&sim).is_empty());
}

/// Raw frames on the line: the same chunk sent twice (a lost ACK) is acknowledged twice but
/// loaded once; a corrupted frame is NAKed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_repeated_chunk_is_acknowledged_again_but_applied_once() {
    use tokio_serial::SerialPortBuilderExt;
    let recs: Vec<StitchRecord> = pattern().into_iter().take(10).collect();
    let sim = spawn_on_pty(fast(SewingSimConfig::default())).unwrap();
    let mut port = tokio_serial::new(&sim.path, 115_200)
        .open_native_async()
        .unwrap();
    let mut dec = Decoder::default();
    async fn exchange(
        port: &mut tokio_serial::SerialStream,
        dec: &mut Decoder,
        bytes: &[u8],
    ) -> Decoded {
        port.write_all(bytes).await.unwrap();
        let mut buf = [0u8; 256];
        loop {
            if let Some(d) = dec.next_frame() {
                return d;
            }
            let n = tokio::time::timeout(Duration::from_secs(2), port.read(&mut buf))
                .await
                .expect("the machine answers")
                .unwrap();
            dec.push(&buf[..n]);
        }
    }
    let mut begin = (recs.len() as u32).to_le_bytes().to_vec();
    begin.extend_from_slice(&pattern_crc(&recs).to_le_bytes());
    let f = Frame::new(1, req::LOAD_BEGIN, begin).encode();
    assert!(
        matches!(exchange(&mut port, &mut dec, &f).await, Decoded::Frame(r) if r.kind == wire::reply::ACK)
    );
    let mut p = 0u32.to_le_bytes().to_vec();
    p.extend_from_slice(&(recs.len() as u16).to_le_bytes());
    recs.iter().for_each(|r| p.extend_from_slice(&r.to_wire()));
    let chunk = Frame::new(2, req::LOAD_CHUNK, p).encode();
    let first = exchange(&mut port, &mut dec, &chunk).await;
    let again = exchange(&mut port, &mut dec, &chunk).await;
    assert_eq!(first, again);
    // a corrupted copy is NAKed
    let mut bad = chunk.clone();
    bad[20] ^= 0x04;
    let nak = exchange(&mut port, &mut dec, &bad).await;
    assert!(
        matches!(nak, Decoded::Frame(ref r) if r.kind == wire::reply::NAK),
        "{nak:?}"
    );
    // the pattern has exactly its 10 records: LOAD_END verifies count and CRC
    let end = Frame::new(3, req::LOAD_END, vec![]).encode();
    match exchange(&mut port, &mut dec, &end).await {
        Decoded::Frame(r) => assert_eq!(r.kind, wire::reply::ACK, "{r:?}"),
        other => panic!("{other:?}"),
    }
    assert_eq!(sim.trace.lock().unwrap().duplicates, 1);
}
