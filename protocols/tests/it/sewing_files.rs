//! DST and JEF files: every step round-trips through our reader, patterns rewrite to the
//! same bytes, headers match the stitches, and pyembroidery (a reader we did not write, from
//! .ci/requirements.txt) reads every needle drop, trim and colour change where we put them.

use machlink_protocols::sewing::{dst, jef, records, RecordLimits, StitchKind, StitchRecord};
use offset_core::geom::{Point, Polyline, Shape};
use offset_core::stitch::{stitch, StitchParams};

use crate::pyembroidery::pyembroidery_read;

fn walk(steps: impl Iterator<Item = (i32, i32, StitchKind)>) -> Vec<StitchRecord> {
    let (mut x, mut y) = (0, 0);
    steps
        .map(|(dx, dy, k)| {
            if k.moves() {
                x += dx;
                y += dy;
            }
            StitchRecord::new(k, x, y)
        })
        .collect()
}

fn every_step(max: i32, kind: StitchKind) -> Vec<StitchRecord> {
    walk((-max..=max).flat_map(move |dx| {
        (-max..=max)
            .filter(move |&dy| !(kind == StitchKind::Jump && dx == 0 && dy == 0))
            .map(move |dy| (dx, dy, kind))
    }))
}

/// A pattern with every kind of record: stitches, jumps, trims, colour changes.
fn mixed_pattern() -> Vec<StitchRecord> {
    let mut steps = vec![(0, 0, StitchKind::Stitch)];
    for i in 0..40 {
        steps.push((25 - i, (i * 7) % 50 - 25, StitchKind::Stitch));
    }
    steps.push((0, 0, StitchKind::Trim));
    steps.push((121, -121, StitchKind::Jump));
    steps.push((-60, 3, StitchKind::Jump));
    steps.push((0, 0, StitchKind::Stitch));
    steps.push((0, 0, StitchKind::ColorChange));
    for i in 0..30 {
        steps.push((-(i % 11), 121 - i, StitchKind::Stitch));
    }
    steps.push((0, 0, StitchKind::Trim));
    walk(steps.into_iter())
}

fn header_field(bytes: &[u8], name: &str) -> String {
    let text = String::from_utf8_lossy(&bytes[..512]).to_string();
    let f = text
        .split('\r')
        .find(|f| f.starts_with(name))
        .unwrap_or_else(|| panic!("no {name} field"));
    f[name.len()..].to_string()
}

#[test]
fn every_dst_step_round_trips_as_stitch_and_jump() {
    for kind in [StitchKind::Stitch, StitchKind::Jump] {
        let recs = every_step(121, kind);
        assert_eq!(recs.len(), 243 * 243 - (kind == StitchKind::Jump) as usize);
        let bytes = dst::write(&recs, "steps").unwrap();
        assert_eq!(bytes.len(), 512 + 3 * recs.len() + 3);
        let back = dst::read(&bytes, "steps.dst").unwrap();
        assert_eq!(back.records, recs);
        assert_eq!(dst::write(&back.records, "steps").unwrap(), bytes);
    }
    for dx in -121..=121 {
        for dy in -121..=121 {
            let b = dst::encode_move(dx, dy, false).unwrap();
            assert_eq!(dst::decode_move(b), (dx, dy));
            assert_eq!(b[2] & 0b11, 0b11);
        }
    }
    assert!(dst::encode_move(122, 0, false).is_none());
    assert!(dst::encode_move(0, -122, true).is_none());
}

#[test]
fn dst_patterns_rewrite_to_the_same_bytes_and_headers_match_the_stitches() {
    let pattern = mixed_pattern();
    let bytes = dst::write(&pattern, "pocket").unwrap();
    let back = dst::read(&bytes, "pocket.dst").unwrap();
    assert_eq!(back.records, pattern);
    assert_eq!(dst::write(&back.records, "pocket").unwrap(), bytes);

    // the header, field by field, against the stitches themselves
    assert_eq!(&bytes[..3], b"LA:");
    assert_eq!(header_field(&bytes, "LA:"), "pocket          ");
    let moving: Vec<&StitchRecord> = pattern.iter().filter(|r| r.kind.moves()).collect();
    let maxx = moving.iter().map(|r| r.x).max().unwrap().max(0);
    let minx = moving.iter().map(|r| r.x).min().unwrap().min(0);
    let maxy = moving.iter().map(|r| r.y).max().unwrap().max(0);
    let miny = moving.iter().map(|r| r.y).min().unwrap().min(0);
    assert_eq!(
        header_field(&bytes, "+X:").trim().parse::<i32>().unwrap(),
        maxx
    );
    assert_eq!(
        header_field(&bytes, "-X:").trim().parse::<i32>().unwrap(),
        -minx
    );
    assert_eq!(
        header_field(&bytes, "+Y:").trim().parse::<i32>().unwrap(),
        maxy
    );
    assert_eq!(
        header_field(&bytes, "-Y:").trim().parse::<i32>().unwrap(),
        -miny
    );
    assert_eq!(back.header.plus_x, maxx);
    let last = moving.last().unwrap();
    let ax: String = header_field(&bytes, "AX:")
        .chars()
        .filter(|c| *c != ' ')
        .collect();
    assert_eq!(ax.parse::<i32>().unwrap(), last.x);
    assert_eq!(back.header.ay, last.y);
    let trims = pattern
        .iter()
        .filter(|r| r.kind == StitchKind::Trim)
        .count();
    let colors = pattern
        .iter()
        .filter(|r| r.kind == StitchKind::ColorChange)
        .count();
    assert_eq!(
        header_field(&bytes, "ST:").trim().parse::<usize>().unwrap(),
        pattern.len() + trims * (dst::TRIM_JUMPS - 1)
    );
    assert_eq!(
        header_field(&bytes, "CO:").trim().parse::<usize>().unwrap(),
        colors
    );
    // fields end in CR, then 0x1A, then spaces to 512; the body ends 00 00 F3
    let eof = bytes.iter().position(|&b| b == 0x1A).unwrap();
    assert_eq!(bytes[eof - 1], b'\r');
    assert!(bytes[eof + 1..512].iter().all(|&b| b == b' '));
    assert_eq!(&bytes[bytes.len() - 3..], &[0x00, 0x00, 0xF3]);
    // a trim is three zero jumps
    let body = &bytes[512..];
    assert!(body
        .windows(9)
        .any(|w| w == [0, 0, 0x83, 0, 0, 0x83, 0, 0, 0x83]));
}

#[test]
fn a_planned_seam_survives_dst_and_jef() {
    let pocket = Polyline::from_points(
        &[
            Point::new(0.0, 0.0),
            Point::new(140.0, 0.0),
            Point::new(140.0, 120.0),
            Point::new(70.0, 150.0),
            Point::new(0.0, 120.0),
        ],
        true,
    );
    let tp = stitch(&Shape::new(vec![pocket]), &StitchParams::default()).unwrap();
    for (limits, dst_file) in [(RecordLimits::DST, true), (RecordLimits::JEF, false)] {
        let recs = records(&tp, limits).unwrap();
        let back = if dst_file {
            dst::read(&dst::write(&recs, "pocket").unwrap(), "p.dst")
                .unwrap()
                .records
        } else {
            jef::read(&jef::write(&recs, &Default::default()).unwrap(), "p.jef").unwrap()
        };
        assert_eq!(back, recs);
        // every needle drop of the plan, in order, in 0.1 mm
        let planned: Vec<(i32, i32)> = tp
            .moves
            .iter()
            .filter_map(|m| match m {
                offset_core::Move::Stitch { to } => {
                    Some(((to.x * 10.0).round() as i32, (to.y * 10.0).round() as i32))
                }
                _ => None,
            })
            .collect();
        let sewn: Vec<(i32, i32)> = back
            .iter()
            .filter(|r| r.kind == StitchKind::Stitch)
            .map(|r| (r.x, r.y))
            .collect();
        assert_eq!(sewn, planned);
    }
}

#[test]
fn every_jef_step_round_trips_and_patterns_rewrite_to_the_same_bytes() {
    for kind in [StitchKind::Stitch, StitchKind::Jump] {
        let recs = every_step(127, kind);
        let bytes = jef::write(&recs, &Default::default()).unwrap();
        let back = jef::read(&bytes, "steps.jef").unwrap();
        assert_eq!(back, recs);
        assert_eq!(jef::write(&back, &Default::default()).unwrap(), bytes);
    }
    let pattern = mixed_pattern();
    let bytes = jef::write(&pattern, &Default::default()).unwrap();
    let back = jef::read(&bytes, "mixed.jef").unwrap();
    assert_eq!(back, pattern);
    assert_eq!(jef::write(&back, &Default::default()).unwrap(), bytes);
    // header: stitch data offset = 0x74 + 8 per thread; thread count = colour changes + 1
    let int = |at: usize| i32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
    assert_eq!(int(24), 2);
    assert_eq!(int(0), 0x74 + 16);
    assert_eq!(&bytes[bytes.len() - 2..], &[0x80, 0x10]);
}

#[test]
fn broken_files_are_one_sentence_naming_the_file() {
    let e = dst::read(b"LA:short", "x.dst").unwrap_err().to_string();
    assert!(e.starts_with("x.dst: ") && e.contains("512"), "{e}");
    let mut ok = dst::write(&mixed_pattern(), "p").unwrap();
    ok.truncate(ok.len() - 3);
    let e = dst::read(&ok, "cut.dst").unwrap_err().to_string();
    assert!(e.contains("cut.dst") && e.contains("end record"), "{e}");
    let mut bad = dst::write(&mixed_pattern(), "p").unwrap();
    bad[512 + 2] = 0x00;
    let e = dst::read(&bad, "bad.dst").unwrap_err().to_string();
    assert!(e.contains("byte 512"), "{e}");
    let e = jef::read(&[1, 2, 3], "x.jef").unwrap_err().to_string();
    assert!(e.starts_with("x.jef: "), "{e}");
    // a stitch too long for one record names it
    let long = vec![StitchRecord::new(StitchKind::Stitch, 122, 0)];
    let e = dst::write(&long, "p").unwrap_err().to_string();
    assert!(e.starts_with("stitch 0 to (12.2, 0.0) mm"), "{e}");
}

/// pyembroidery's command numbers (EmbConstant).
const PY_STITCH: u32 = 0;
const PY_TRIM: u32 = 2;
const PY_COLOR_CHANGE: u32 = 5;

#[test]
fn pyembroidery_reads_our_dst_and_jef_as_the_same_stitches_trims_and_colour_changes() {
    let dir = tempfile::tempdir().unwrap();
    let pocket = Polyline::from_points(
        &[
            Point::new(0.0, 0.0),
            Point::new(140.0, 0.0),
            Point::new(140.0, 120.0),
            Point::new(70.0, 150.0),
            Point::new(0.0, 120.0),
        ],
        true,
    );
    let seam = stitch(&Shape::new(vec![pocket]), &StitchParams::default()).unwrap();
    for (name, limits) in [("dst", RecordLimits::DST), ("jef", RecordLimits::JEF)] {
        for (what, recs) in [
            ("mixed", mixed_pattern()),
            ("seam", records(&seam, limits).unwrap()),
        ] {
            let bytes = if name == "dst" {
                dst::write(&recs, what).unwrap()
            } else {
                jef::write(&recs, &Default::default()).unwrap()
            };
            let path = dir.path().join(format!("{what}.{name}"));
            std::fs::write(&path, &bytes).unwrap();
            // pyembroidery's units are ours (0.1 mm): whole numbers, rounded as it stores them
            let theirs: Vec<(i32, i32, u32)> = pyembroidery_read(&path)
                .into_iter()
                .map(|(x, y, c)| (x.round() as i32, y.round() as i32, c))
                .collect();
            // every needle drop in order, at our coordinates (pyembroidery's y points down)
            let ours: Vec<(i32, i32)> = recs
                .iter()
                .filter(|r| r.kind == StitchKind::Stitch)
                .map(|r| (r.x, -r.y))
                .collect();
            let read: Vec<(i32, i32)> = theirs
                .iter()
                .filter(|r| r.2 == PY_STITCH)
                .map(|r| (r.0, r.1))
                .collect();
            assert!(ours.len() > 30, "{what}.{name}: {} stitches", ours.len());
            assert_eq!(
                read, ours,
                "{what}.{name}: pyembroidery reads other stitches"
            );
            let count = |k: StitchKind| recs.iter().filter(|r| r.kind == k).count();
            let py_count = |c: u32| theirs.iter().filter(|r| r.2 == c).count();
            assert_eq!(
                py_count(PY_COLOR_CHANGE),
                count(StitchKind::ColorChange),
                "{what}.{name}: colour changes"
            );
            if name == "dst" {
                // a DST trim is three zero jumps, which pyembroidery reads back as a trim
                assert_eq!(
                    py_count(PY_TRIM),
                    count(StitchKind::Trim),
                    "{what}.dst: trims"
                );
            }
        }
    }
}
