//! Fuzz-style properties of every parser that reads what a device sends, and of the G-code
//! reader: any input is parsed or refused, never a panic, in time bounded by its length.
//! Cases per property: 5000, scaled by `PROPTEST_CASES / 256`.

use machlink_protocols::gcode_read;
use machlink_protocols::grbl::reply::{classify, parse_opt, parse_status};
use machlink_protocols::modbus::map::{Layout, MotionBlock, Status, WordOrder};
use machlink_protocols::sewing::wire::{self, Decoded, Decoder, Frame};
use machlink_protocols::untrusted::{printable, LineSplitter};
use proptest::prelude::*;

/// 5000 cases, or `PROPTEST_CASES` when set, like every property test (docs/testing.md).
fn cases() -> u32 {
    offset_core::check::proptest_cases(5000)
}

/// Text shaped like GRBL's replies: fragments of real ones, glued and cut.
fn grbl_like() -> impl Strategy<Value = String> {
    let pieces = prop::sample::select(vec![
        "ok",
        "error:",
        "ALARM:",
        "<",
        ">",
        "|",
        "Idle",
        "Hold:",
        "Run",
        "MPos:",
        "WPos:",
        "WCO:",
        "Bf:",
        "FS:",
        "F:",
        "Ln:",
        "Ov:",
        ",",
        ":",
        "-",
        ".",
        "1",
        "0",
        "9",
        "e9",
        "[MSG:",
        "[OPT:",
        "]",
        "Grbl ",
        "\u{1b}",
        "\u{0}",
        "é",
        " ",
        "NaN",
        "inf",
        "99999999999999999999",
    ]);
    prop::collection::vec(pieces, 0..24).prop_map(|v| v.concat())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(cases()))]

    #[test]
    fn grbl_replies_never_panic(s in grbl_like(), raw in ".{0,200}") {
        for line in [&s, &raw] {
            let _ = classify(line);
            let _ = parse_opt(line);
            if let Some(r) = parse_status(line) {
                let st = r.to_status(None);
                let _ = st.state.to_string();
            }
        }
    }

    #[test]
    fn device_lines_are_bounded_and_printable(bytes in prop::collection::vec(any::<u8>(), 0..4096), max in 1usize..300) {
        let mut s = LineSplitter::new(max);
        let mut lines = Vec::new();
        let r = s.push(&bytes, |l| lines.push(l));
        for l in &lines {
            prop_assert!(l.chars().all(|c| !c.is_control()), "{l:?}");
            prop_assert!(l.chars().count() <= max + 1);
        }
        prop_assert!(s.pending() <= max);
        if r.is_ok() {
            let p = printable(&String::from_utf8_lossy(&bytes), max);
            prop_assert!(p.chars().all(|c| !c.is_control()));
        }
    }

    #[test]
    fn sewing_frames_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..3000)) {
        let mut d = Decoder::default();
        for chunk in bytes.chunks(97) {
            d.push(chunk);
            let mut n = 0;
            while let Some(f) = d.next_frame() {
                if let Decoded::Frame(f) = f {
                    let _ = wire::Status::decode(&f.payload);
                    let _ = wire::Info::decode(&f.payload);
                }
                n += 1;
                prop_assert!(n <= wire::MAX_PAYLOAD + 7 + chunk.len());
            }
            prop_assert!(d.pending() <= wire::MAX_PAYLOAD + 7 + chunk.len());
        }
        d.resync_on_idle();
        while d.next_frame().is_some() {}
        prop_assert_eq!(d.pending(), 0);
    }

    #[test]
    fn damaged_sewing_frames_are_refused_or_read(seq in any::<u8>(), kind in any::<u8>(),
            payload in prop::collection::vec(any::<u8>(), 0..200),
            edits in prop::collection::vec((any::<usize>(), any::<u8>()), 0..6)) {
        let mut bytes = Frame::new(seq, kind, payload.clone()).encode();
        for (at, b) in &edits {
            let i = at % bytes.len();
            bytes[i] = *b;
        }
        let mut d = Decoder::default();
        d.push(&bytes);
        let mut frames = 0;
        while let Some(f) = d.next_frame() {
            if let Decoded::Frame(_) = f { frames += 1; }
        }
        // the line goes quiet: what is left is dropped or read
        d.resync_on_idle();
        while let Some(f) = d.next_frame() {
            if let Decoded::Frame(_) = f { frames += 1; }
        }
        prop_assert_eq!(d.pending(), 0);
        if edits.is_empty() {
            prop_assert_eq!(frames, 1);
        }
    }

    #[test]
    fn modbus_replies_of_any_length_never_panic(regs in prop::collection::vec(any::<u16>(), 0..40),
            low_first in any::<bool>(), base in any::<u16>(), capacity in any::<u16>(),
            seq in any::<u32>(), addr in any::<u16>(), count in any::<u16>()) {
        let order = if low_first { WordOrder::LowFirst } else { WordOrder::HighFirst };
        let _ = Status::decode(&regs, order);
        let _ = MotionBlock::decode(&regs, order);
        let l = Layout { base, capacity };
        let slot = l.slot(seq);
        prop_assert!(capacity == 0 || slot < capacity);
        let _ = l.slot_address(slot);
        let _ = l.end();
        let _ = l.describe(addr, count);
    }

    #[test]
    fn gcode_reader_never_panics(lines in prop::collection::vec(
            prop::collection::vec(prop::sample::select(vec![
                "G0", "G1", "G2", "G3", "G20", "G21", "G90", "G91", "G53", "G28", "X", "Y",
                "Z", "I", "J", "R", "F", "1", "-0.5", "1e308", "9e999", "nan", "(", ")", ";",
                "%", "$", " ", ".", "+", "M3", "S", "\u{0}", "é"]), 0..12)
            .prop_map(|w| w.concat()), 0..30)) {
        let _ = gcode_read::read(&lines.join("\n"));
    }

    #[test]
    fn gcode_reader_takes_any_text(text in ".{0,400}") {
        let _ = gcode_read::read(&text);
    }
}
