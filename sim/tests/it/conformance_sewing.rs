//! docs/sewing-link.md's state table, cell by cell, against the simulated pattern sewing
//! machine (the reference machine): one test per request row, each taking a fresh machine
//! to every state and checking the answer, the next state, the stitch counter and the
//! pattern STATUS names.

use machlink_protocols::sewing::dst;
use machlink_protocols::sewing::{records, RecordLimits};
use machlink_sim::conformance::sewing::{
    check, markdown_table, Ask, ASKS, COLUMNS, THREAD_BREAK_AT,
};
use machlink_sim::conformance::{document_holds, every_column};
use machlink_sim::line;
use machlink_sim::sewing::{spawn_on, SewingSimConfig};

/// Every state of `ask`'s row, on a fresh machine each.
async fn row(ask: Ask) {
    every_column(&COLUMNS, ask.text(), |column| async move {
        let (host, dev) = line::cable(None);
        let cfg = SewingSimConfig {
            time_scale: 1.0,
            thread_break_at: vec![THREAD_BREAK_AT],
            ..SewingSimConfig::default()
        };
        let machine = spawn_on(dev, cfg, Default::default());
        let r = check(host, column, ask).await;
        machine.abort();
        r
    })
    .await;
}

machlink_sim::conformance_rows! {
    row, ASKS;
    info => Ask::Info,
    status => Ask::Status,
    load_begin => Ask::LoadBegin,
    load_chunk_at_the_next_offset => Ask::ChunkNext,
    load_chunk_of_records_already_loaded => Ask::ChunkRepeat,
    load_chunk_past_the_records_loaded => Ask::ChunkGap,
    load_end_with_a_good_pattern => Ask::LoadEnd,
    load_end_with_a_bad_pattern_crc => Ask::LoadEndBadCrc,
    start_inside_the_pattern => Ask::Start,
    start_naming_another_crc => Ask::StartOtherCrc,
    start_past_the_end => Ask::StartPastEnd,
    start_at_the_end => Ask::StartAtEnd,
    stop => Ask::Stop,
    resume => Ask::Resume,
    abort => Ask::Abort,
    an_unknown_request_type => Ask::UnknownType,
    a_frame_with_a_bad_crc => Ask::BadCrc,
    a_frame_that_stops_short => Ask::StoppedShort,
    the_last_request_again => Ask::Repeat,
}

#[test]
fn the_document_holds_the_table_this_test_runs() {
    document_holds("sewing-link.md", &markdown_table()).unwrap();
}

/// The records the link sends are the DST post's records: the same origin, one trim record
/// for each DST trim, nothing added or dropped (a stop is the one thing DST cannot tell from
/// a colour change).
#[test]
fn the_link_sends_the_records_the_dst_file_holds() {
    use offset_core::geom::{Point, Polyline, Shape};
    use offset_core::stitch::{stitch, StitchParams};
    let seams = Shape::new(vec![
        Polyline::rect(Point::new(-20.0, 0.0), Point::new(20.0, 20.0)),
        Polyline::rect(Point::new(30.0, 5.0), Point::new(50.0, 25.0)),
    ]);
    let p = StitchParams {
        stitch_length: 2.0,
        tie: true,
        ..Default::default()
    };
    let tp = stitch(&seams, &p).unwrap();
    let recs = records(&tp, RecordLimits::DST).unwrap();
    assert!(recs
        .iter()
        .any(|r| r.kind == machlink_protocols::sewing::StitchKind::Trim));
    let file = dst::write(&recs, "doc").unwrap();
    assert_eq!(dst::read_dst(&file, "doc.dst").unwrap(), recs);
}
