//! A stitch job through the daemon to the simulated pattern sewing machine: line noise and a
//! thread break on the way, every planned stitch sewn exactly once and in order.

mod common;

use common::*;
use machlink::core::intake::{self, JobSpec, Operation, Target};
use machlink::core::store::JobState;
use machlink::daemon::StartOptions;
use machlink_protocols::sewing::{StitchKind, StitchRecord};
use machlink_sim::sewing::SewingSim;
use offset_core::stitch::StitchParams;

const POCKET: &str = r#"{ "units": "mm", "paths": [ { "closed": true,
  "vertices": [[-60,-40,0],[60,-40,0],[60,40,0],[0,60,0],[-60,40,0]] } ] }"#;

const BREAK_AT: u32 = 180;

fn machine() -> String {
    format!(
        "[[machine]]\nname = \"pocket-setter\"\nlink = \"sim-sewing\"\ntime_scale = 20\nspm = 3000\n\
         noise = 0.002\nthread_break_at = [{BREAK_AT}]\n"
    )
}

fn pocket_job() -> JobSpec {
    JobSpec {
        operation: Some(Operation::Stitch(StitchParams {
            stitch_length: 2.5,
            rows: vec![0.0, -3.0],
            tie: true,
            ..Default::default()
        })),
        ..job("pocket-setter", "pocket.json", POCKET)
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_thread_break_pauses_the_job_and_resume_sews_every_stitch_once() {
    let dir = tempfile::tempdir().unwrap();
    let d = start(dir.path(), &machine(), StartOptions::default()).await;
    let c = client(&d);
    let job = c.submit(&pocket_job()).await.expect("submitted");
    // the program the daemon planned, planned again here
    let cfg = d.scheduler.machine_config("pocket-setter").unwrap().clone();
    let planned = intake::plan(&pocket_job(), Target::Machine(&cfg)).unwrap();
    let records = planned.program.units::<StitchRecord>().unwrap().to_vec();
    assert_eq!(stored::<StitchRecord>(&d, job.id), records);
    assert_eq!(job.total_units, records.len());
    let planned: Vec<(u32, i32, i32)> = records
        .iter()
        .enumerate()
        .filter(|(_, r)| r.kind == StitchKind::Stitch)
        .map(|(i, r)| (i as u32, r.x, r.y))
        .collect();
    let sim = d.device::<SewingSim>("pocket-setter").unwrap();
    let sewn = || -> Vec<(u32, i32, i32)> {
        let t = sim.trace.lock().unwrap();
        t.drops.iter().map(|n| (n.index, n.x, n.y)).collect()
    };

    // the thread breaks at record 180: the job pauses there
    let paused = wait_state(&c, job.id, JobState::Paused).await;
    assert!(paused.acked_units <= BREAK_AT as usize);
    tokio::time::sleep(std::time::Duration::from_millis(200)).await;
    let before = sewn();
    assert!(
        before.iter().all(|(i, _, _)| *i < BREAK_AT),
        "sewed past the break"
    );
    assert_eq!(before, planned[..before.len()].to_vec());
    assert_eq!(
        c.act(job.id, "resume").await.unwrap().state,
        JobState::Running
    );
    let done = wait_end(&c, job.id).await;
    assert_eq!(done.state, JobState::Completed, "{:?}", done.error);
    assert_eq!(done.acked_units, records.len());
    // exactly the planned stitches, in order, none twice
    assert_eq!(sewn(), planned);
    let t = sim.trace.lock().unwrap();
    assert!(t.events.contains(&format!("thread break at {BREAK_AT}")));
    assert!(
        t.corrupt_frames + t.duplicates > 0,
        "the line noise never hit a frame"
    );
}

/// A stitch job with two rows, planned for the DST post and written as a DST file, reads
/// back through our DST reader as the same records, with a seam on the outline and one 3 mm
/// inside. This runs the library's planning, not the binary: `machlink plan --op stitch
/// --post dst|jef`, read back by pyembroidery, is daemon/tests/posts_cli.rs.
#[test]
fn a_two_row_stitch_plan_written_as_dst_reads_back_with_both_rows() {
    use machlink_protocols::sewing::dst;
    let spec = JobSpec {
        machine: None,
        ..pocket_job()
    };
    let registry = machlink::core::registry::standard();
    let post = registry.post("dst").unwrap();
    let planned = intake::plan(&spec, Target::Post(post)).unwrap();
    let records = planned.program.units::<StitchRecord>().unwrap().to_vec();
    assert_eq!(
        post.file(&planned.program, "pocket").unwrap(),
        dst::write(&records, "pocket").unwrap()
    );
    let shape = planned.shape.unwrap();
    let bytes = dst::write(&records, "pocket").unwrap();
    let back = dst::read(&bytes, "pocket.dst").unwrap();
    assert_eq!(back.records, records);
    // two seams (outline and the row 3 mm inside), stitches of at most 2.5 mm + rounding
    let outline = &shape.paths[0];
    let (mut on, mut inside) = (0, 0);
    let mut prev = (0, 0);
    for r in &back.records {
        if r.kind == StitchKind::Stitch {
            let d = (((r.x - prev.0).pow(2) + (r.y - prev.1).pow(2)) as f64).sqrt();
            assert!(d <= 25.0 + 1.5, "a {d} stitch");
            let q = r.mm();
            let dist = outline.distance_to(q);
            if dist < 0.2 {
                on += 1;
            } else {
                assert!(outline.contains(q) && dist > 2.8, "{q:?} is {dist} mm off");
                inside += 1;
            }
        }
        if r.kind.moves() {
            prev = (r.x, r.y);
        }
    }
    assert!(
        on > 100 && inside > 100,
        "{on} on the outline, {inside} inside"
    );
    assert_eq!(back.header.plus_x, 600);
    assert_eq!(back.header.plus_y, 600);
}
