//! The CANopen decoders never panic, whatever bytes arrive: SLCAN lines from a serial port,
//! SDO responses to the client, SDO requests to the server, and the broadcast services; and
//! frames survive SLCAN encoding whatever noise and chunking surround them.
//! (4000 cases per property, scaled by PROPTEST_CASES / 256.)

use machlink_protocols::canopen::nmt::{self, Emcy, NmtCommand};
use machlink_protocols::canopen::pdo::{Mapped, Pdo};
use machlink_protocols::canopen::sdo::{AbortCode, ObjectAccess, SdoClient, SdoServer};
use machlink_protocols::canopen::slcan::{encode_frame, LineDecoder, SlcanLine, MAX_LINE};
use machlink_protocols::canopen::{od, CanFrame};
use proptest::prelude::*;
use std::collections::BTreeMap;

fn frame() -> impl Strategy<Value = CanFrame> {
    (
        any::<bool>(),
        any::<u32>(),
        proptest::collection::vec(any::<u8>(), 0..=8),
        any::<bool>(),
    )
        .prop_map(|(ext, id, data, rtr)| {
            let id = if ext { id & 0x1FFF_FFFF } else { id & 0x7FF };
            if rtr {
                CanFrame::remote(id, ext, data.len() as u8).unwrap()
            } else {
                CanFrame::with_id(id, ext, &data).unwrap()
            }
        })
}

#[derive(Default)]
struct Dict(BTreeMap<(u16, u8), Vec<u8>>);

impl ObjectAccess for Dict {
    fn read(&mut self, index: u16, sub: u8) -> Result<Vec<u8>, AbortCode> {
        self.0
            .get(&(index, sub))
            .cloned()
            .ok_or(AbortCode::NO_OBJECT)
    }
    fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), AbortCode> {
        if data.len() > 64 {
            return Err(AbortCode::TOO_LONG);
        }
        self.0.insert((index, sub), data.to_vec());
        Ok(())
    }
}

proptest! {
    // thousands of byte sequences per decoder, scaled by PROPTEST_CASES / 256
    #![proptest_config(ProptestConfig::with_cases(offset_core::check::proptest_cases(4000)))]
    #[test]
    fn the_slcan_decoder_takes_any_bytes_in_any_chunks(chunks in proptest::collection::vec(proptest::collection::vec(any::<u8>(), 0..64), 0..32)) {
        let mut d = LineDecoder::new();
        let mut out = Vec::new();
        for c in &chunks {
            d.push(c, &mut out);
        }
        for line in &out {
            if let SlcanLine::Other(t) = line {
                prop_assert!(t.len() <= MAX_LINE * 3, "a kept line is bounded: {}", t.len());
            }
        }
    }

    #[test]
    fn frames_come_through_noise_and_any_chunking(frames in proptest::collection::vec(frame(), 1..20), noise in proptest::collection::vec("[A-QSU-Zc-qsu-y0-9 ]{0,60}", 0..20), cut in 1usize..17) {
        let mut bytes = Vec::new();
        for (i, f) in frames.iter().enumerate() {
            if let Some(n) = noise.get(i) {
                bytes.extend_from_slice(n.as_bytes());
                bytes.push(b'\r');
            }
            encode_frame(f, &mut bytes);
        }
        let mut d = LineDecoder::new();
        let mut out = Vec::new();
        for c in bytes.chunks(cut) {
            d.push(c, &mut out);
        }
        let got: Vec<CanFrame> = out.into_iter().filter_map(|l| match l {
            SlcanLine::Frame(f) => Some(f),
            _ => None,
        }).collect();
        // noise never makes up a frame here: it has no t, T, r or R
        prop_assert_eq!(got, frames);
    }

    #[test]
    fn the_sdo_client_takes_any_response_in_any_state(start in 0u8..3, responses in proptest::collection::vec(proptest::collection::vec(any::<u8>(), 0..12), 0..16)) {
        let mut c = SdoClient::new();
        match start {
            0 => { c.upload(0x1008, 0); }
            1 => { c.download(0x2000, 1, &[1, 2, 3]); }
            _ => { c.download(0x2000, 1, &[7; 20]); }
        }
        for r in &responses {
            let _ = c.on_response(r);
        }
    }

    #[test]
    fn the_sdo_client_survives_a_server_of_random_but_plausible_answers(answers in proptest::collection::vec((0u8..8, any::<[u8; 7]>()), 0..20)) {
        // command bytes from every specifier, so segmented paths are reached too
        let mut c = SdoClient::new();
        c.upload(0x1008, 0);
        for (scs, rest) in &answers {
            let mut f = [0u8; 8];
            f[0] = (scs << 5) | (rest[0] & 0x1F);
            f[1..].copy_from_slice(&[0x08, 0x10, 0, rest[3], rest[4], rest[5], rest[6]]);
            let _ = c.on_response(&f);
        }
    }

    #[test]
    fn the_sdo_server_takes_any_requests(requests in proptest::collection::vec(proptest::collection::vec(any::<u8>(), 0..12), 0..32)) {
        let mut s = SdoServer::new();
        let mut dict = Dict::default();
        dict.0.insert((0x1008, 0), b"a device name longer than four bytes".to_vec());
        dict.0.insert((0x1000, 0), vec![0x92, 0x01, 0x02, 0x00]);
        for r in &requests {
            if let Some(answer) = s.on_request(r, &mut dict) {
                prop_assert_eq!(answer.len(), 8);
            }
        }
    }

    #[test]
    fn the_broadcast_parsers_take_any_frame(f in frame()) {
        let _ = NmtCommand::parse(&f);
        let _ = nmt::parse_heartbeat(&f);
        let _ = Emcy::parse(&f).map(|e| e.to_string());
        let _ = nmt::is_sync(&f);
        let p = Pdo::tpdo(1, 1, vec![Mapped::new(od::POSITION_ACTUAL, 32), Mapped::new(od::FOLLOWING_ERROR, 32)]);
        let _ = p.unpack(f.data());
        let _ = f.bits_on_wire();
    }
}
