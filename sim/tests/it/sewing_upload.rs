//! Pattern upload through line noise, timed on the simulator's own clock: the machine and
//! the link talk over an in-memory cable that the machine paces at 115200 baud, under
//! tokio's paused clock. Every byte then takes exactly its time on the line and every
//! timeout exactly its length, so the upload's duration on that clock is what it would take
//! on a real 115200-baud line, the same on every machine the test runs on. That is what the
//! test compares (noisy against clean, both measured here); wall-clock time is the
//! benchmark's (sim/benches/sewing_bench.rs).

use machlink_protocols::sewing::link::{SewingLink, SewingTiming};
use machlink_protocols::sewing::wire::SewingState;
use machlink_protocols::sewing::{pattern_crc, StitchKind, StitchRecord};
use machlink_sim::line;
use machlink_sim::sewing::{spawn_on, SewingSimConfig, Trace};
use std::time::Duration;
use tokio::time::Instant;

const BAUD: u32 = 115_200;

/// A serpentine of 0.5 mm stitches, 1 mm between rows, inside the sewing area.
fn serpentine(n: i32) -> Vec<StitchRecord> {
    (0..n)
        .map(|i| {
            let (row, col) = (i / 200, i % 200);
            let x = if row % 2 == 0 { col * 5 } else { 995 - col * 5 };
            StitchRecord::new(StitchKind::Stitch, x, row * 10)
        })
        .collect()
}

struct Upload {
    took: Duration,
    window: u8,
    retransmissions: u64,
    naks: u64,
}

/// Uploads `records` to a machine reporting `window` (None: protocol version 1) through
/// `noise` per byte each way, and checks that the machine verified exactly this pattern.
async fn upload(records: &[StitchRecord], noise: f64, window: Option<u8>) -> Upload {
    let (host, dev) = line::cable(None);
    let trace = Trace::default();
    let cfg = SewingSimConfig {
        noise,
        seed: 17,
        baud: Some(BAUD),
        window,
        ..SewingSimConfig::default()
    };
    let machine = spawn_on(dev, cfg, trace.clone());
    let mut link = SewingLink::new(host, SewingTiming::default());
    let t = Instant::now();
    link.upload(records).await.expect("the upload goes through");
    let took = t.elapsed();
    // LOAD_END was acknowledged: the machine checked the count and the whole-pattern
    // CRC-32 against its records. Its status names that pattern.
    let st = link.status().await.unwrap();
    assert_eq!(st.state, SewingState::Ready);
    assert_eq!(st.pattern_len as usize, records.len());
    assert_eq!(st.pattern_crc, pattern_crc(records));
    let naks = trace.lock().unwrap().corrupt_frames;
    assert!(trace
        .lock()
        .unwrap()
        .events
        .contains(&format!("pattern verified ({} records)", records.len())));
    machine.abort();
    Upload {
        took,
        window: link.window(),
        retransmissions: link.retransmissions,
        naks,
    }
}

#[tokio::test(start_paused = true)]
async fn twenty_thousand_records_at_0_2_percent_noise_upload_exactly_in_under_twice_the_clean_time()
{
    let records = serpentine(20_000);
    let clean = upload(&records, 0.0, Some(4)).await;
    let noisy = upload(&records, 0.002, Some(4)).await;
    assert_eq!((clean.window, noisy.window), (2, 2), "the window agreed");
    assert_eq!(clean.retransmissions, 0);
    assert!(
        noisy.retransmissions > 50 && noisy.naks > 50,
        "the noise hit: {} retransmissions, {} NAKs",
        noisy.retransmissions,
        noisy.naks
    );
    // 180,000 bytes of records at 11,520 bytes/s: the clean upload is within 5 % of the line
    let line = Duration::from_secs_f64(20_000.0 * 9.0 / (BAUD as f64 / 10.0));
    assert!(
        clean.took < line.mul_f64(1.05),
        "clean {:?}, the line alone {line:?}",
        clean.took
    );
    assert!(
        noisy.took < clean.took * 2,
        "0.2 % noise took {:?}, the clean upload {:?}",
        noisy.took,
        clean.took
    );
}

#[tokio::test(start_paused = true)]
async fn a_machine_that_reports_window_1_gets_one_chunk_at_a_time_through_noise() {
    let records = serpentine(3_000);
    let u = upload(&records, 0.002, Some(1)).await;
    assert_eq!(u.window, 1);
    assert!(u.retransmissions > 0);
}

#[tokio::test(start_paused = true)]
async fn a_machine_of_protocol_version_1_without_a_window_still_takes_the_upload() {
    let records = serpentine(3_000);
    let u = upload(&records, 0.002, None).await;
    assert_eq!(u.window, 1);
    assert!(u.retransmissions > 0);
}
