//! Helpers the Modbus tests share: a test job and the exactly-once check.
#![allow(dead_code)]

use machlink_protocols::modbus::{post_blocks, MotionBlock};
use machlink_protocols::LinkEvent;
use machlink_sim::modbus::ModbusSim;
use offset_core::{Move, Point, Toolpath, P3};

/// A job of `n` moves: a zig-zag of short lines with an arc every tenth move.
pub fn job(n: usize) -> Vec<MotionBlock> {
    let mut tp = Toolpath::new("test zig-zag");
    tp.push(Move::Rapid {
        to: P3::new(0.0, 0.0, 2.0),
    });
    let mut x = 0.0;
    for i in 1..n {
        let y = if i % 2 == 0 { 0.0 } else { 0.5 };
        let to = P3::new(x + 0.1, y, -0.5);
        if i % 10 == 0 {
            tp.push(Move::Arc {
                to,
                center: Point::new(x + 0.05, (y + 0.25) % 0.5),
                ccw: i % 20 == 0,
                feed: 600.0,
            });
        } else {
            tp.push(Move::Linear { to, feed: 600.0 });
        }
        x += 0.1;
    }
    post_blocks(&tp).expect("the job fits 32-bit micrometres")
}

/// Every block of the job executed once, in order, and the acknowledgements only grew.
pub fn assert_exactly_once(sim: &ModbusSim, blocks: &[MotionBlock], events: &[LinkEvent]) {
    let trace = sim.trace();
    assert_eq!(
        trace.len(),
        blocks.len(),
        "executed {} of {} blocks",
        trace.len(),
        blocks.len()
    );
    for (i, (e, b)) in trace.iter().zip(blocks).enumerate() {
        assert_eq!(e.seq as usize, i + 1, "block {i} executed out of order");
        assert_eq!(&e.block, b, "block {i} arrived changed");
    }
    let acks: Vec<usize> = events
        .iter()
        .filter_map(|e| match e {
            LinkEvent::Acked { unit } => Some(*unit),
            _ => None,
        })
        .collect();
    assert!(
        acks.windows(2).all(|w| w[0] < w[1]),
        "acks went back: {acks:?}"
    );
    assert_eq!(acks.last(), Some(&(blocks.len() - 1)));
}
