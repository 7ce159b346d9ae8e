//! The Modbus post: Toolpath IR → motion blocks in integer micrometres, ending with an end block.

use super::map::{BlockKind, MotionBlock};
use crate::post::{lines_file, Post, PostError};
use offset_core::toolpath::{Move, P3};
use offset_core::Toolpath;

/// Why a tool path cannot become motion blocks.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ModbusPostError {
    #[error("move {index}: {axis} = {value} mm does not fit a signed 32-bit count of micrometres (±2147.483647 m)")]
    Overflow {
        index: usize,
        axis: &'static str,
        value: f64,
    },
    #[error("move {index}: feed {value} mm/min is not a positive number below 4294967 mm/min")]
    BadFeed { index: usize, value: f64 },
    #[error("move {index}: dwell of {value} s is not between 0 and 4294967 s")]
    BadDwell { index: usize, value: f64 },
    #[error("move {index}: a motion-block device has no {what}; {instead}")]
    Unsupported {
        index: usize,
        what: &'static str,
        /// What the operator can do instead.
        instead: &'static str,
    },
}

fn um(index: usize, axis: &'static str, mm: f64) -> Result<i32, ModbusPostError> {
    let v = (mm * 1000.0).round();
    if v.is_finite() && v >= i32::MIN as f64 && v <= i32::MAX as f64 {
        Ok(v as i32)
    } else {
        Err(ModbusPostError::Overflow {
            index,
            axis,
            value: mm,
        })
    }
}

fn feed(index: usize, f: f64) -> Result<u32, ModbusPostError> {
    let v = (f * 1000.0).round();
    if f.is_finite() && f > 0.0 && v <= u32::MAX as f64 {
        Ok(v.max(1.0) as u32)
    } else {
        Err(ModbusPostError::BadFeed { index, value: f })
    }
}

fn target(index: usize, p: P3) -> Result<[i32; 3], ModbusPostError> {
    Ok([
        um(index, "X", p.x)?,
        um(index, "Y", p.y)?,
        um(index, "Z", p.z)?,
    ])
}

/// Turns a tool path into motion blocks. Spindle and comment moves have no block (a drive or
/// PLC handles them itself) and are left out; a tool change is a tool block, at which the
/// device holds for the operator (docs/modbus.md); sewing moves, program stops and probes
/// are refused. The last block is always `End`.
pub fn post_blocks(tp: &Toolpath) -> Result<Vec<MotionBlock>, ModbusPostError> {
    // drilling cycles go as the rapids, lines and dwells they make
    let expanded = tp.expanded();
    let tp = &expanded;
    let mut out = Vec::with_capacity(tp.moves.len() + 1);
    let mut pos = P3::default();
    let mut last = [0i32; 3];
    for (index, m) in tp.moves.iter().enumerate() {
        let block = match m {
            // the device holds at it until the operator has loaded the tool and resumes
            Move::ToolChange { tool, .. } => MotionBlock {
                kind: BlockKind::ToolChange,
                target: last,
                feed: *tool,
                center: [0, 0],
            },
            Move::Rapid { to } => MotionBlock {
                kind: BlockKind::Rapid,
                target: target(index, *to)?,
                feed: 0,
                center: [0, 0],
            },
            Move::Linear { to, feed: f } => MotionBlock {
                kind: BlockKind::Linear,
                target: target(index, *to)?,
                feed: feed(index, *f)?,
                center: [0, 0],
            },
            Move::Arc {
                to,
                center,
                ccw,
                feed: f,
            } => MotionBlock {
                kind: if *ccw {
                    BlockKind::ArcCcw
                } else {
                    BlockKind::ArcCw
                },
                target: target(index, *to)?,
                feed: feed(index, *f)?,
                center: [
                    um(index, "I", center.x - pos.x)?,
                    um(index, "J", center.y - pos.y)?,
                ],
            },
            Move::Dwell { seconds } => {
                let ms = (seconds * 1000.0).round();
                if !(ms.is_finite() && ms >= 0.0 && ms <= u32::MAX as f64) {
                    return Err(ModbusPostError::BadDwell {
                        index,
                        value: *seconds,
                    });
                }
                MotionBlock {
                    kind: BlockKind::Dwell,
                    target: last,
                    feed: ms as u32,
                    center: [0, 0],
                }
            }
            Move::Spindle { .. } | Move::Comment { .. } | Move::Drill { .. } => continue,
            Move::Stitch { .. } | Move::Jump { .. } | Move::Trim | Move::ColorChange => {
                return Err(ModbusPostError::Unsupported {
                    index,
                    what: "needle or thread",
                    instead: "plan this job for a sewing machine",
                })
            }
            Move::Stop => {
                return Err(ModbusPostError::Unsupported {
                    index,
                    what: "program stop block",
                    instead: "submit the part before the stop and the part after it as two jobs",
                })
            }
            Move::ProbeToolLength { .. } => {
                return Err(ModbusPostError::Unsupported {
                    index,
                    what: "tool-length probe",
                    instead: "set the tool length at the machine instead",
                })
            }
        };
        if let Move::Rapid { to } | Move::Linear { to, .. } | Move::Arc { to, .. } = m {
            pos = *to;
        }
        last = block.target;
        out.push(block);
    }
    out.push(MotionBlock {
        kind: BlockKind::End,
        target: last,
        feed: 0,
        center: [0, 0],
    });
    Ok(out)
}

/// The Modbus post: units are motion blocks; the file is one block per line as text
/// (docs/modbus.md).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ModbusPost;

impl Post for ModbusPost {
    type Unit = MotionBlock;
    fn name(&self) -> &'static str {
        "modbus"
    }
    fn about(&self) -> &'static str {
        "motion blocks for a Modbus ring buffer (docs/modbus.md), one block per line"
    }
    fn extension(&self) -> &'static str {
        "blocks"
    }
    fn units(&self, tp: &Toolpath) -> Result<Vec<MotionBlock>, PostError> {
        post_blocks(tp).map_err(|e| PostError::new("modbus", e))
    }
    fn file(&self, blocks: &[MotionBlock], _label: &str) -> Result<Vec<u8>, PostError> {
        Ok(lines_file(blocks))
    }
}

impl crate::program::Unit for MotionBlock {
    fn describe(&self) -> String {
        self.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use offset_core::geom::Point;

    #[test]
    fn arcs_carry_centre_relative_to_their_start_and_the_program_ends() {
        let mut tp = Toolpath::new("t");
        tp.push(Move::Rapid {
            to: P3::new(10.0, 0.0, 5.0),
        });
        tp.push(Move::Spindle { rpm: 1000.0 });
        tp.push(Move::Arc {
            to: P3::new(-10.0, 0.0, 5.0),
            center: Point::new(0.0, 0.0),
            ccw: true,
            feed: 800.5,
        });
        let b = post_blocks(&tp).unwrap();
        assert_eq!(b.len(), 3);
        assert_eq!(b[1].kind, BlockKind::ArcCcw);
        assert_eq!(b[1].center, [-10_000, 0]);
        assert_eq!(b[1].feed, 800_500);
        assert_eq!(b[2].kind, BlockKind::End);
        assert_eq!(b[2].target, [-10_000, 0, 5_000]);
    }

    #[test]
    fn overflow_names_the_move_and_axis() {
        let mut tp = Toolpath::new("t");
        tp.push(Move::Linear {
            to: P3::new(0.0, 3_000_000.0, 0.0),
            feed: 100.0,
        });
        let e = post_blocks(&tp).unwrap_err();
        assert_eq!(
            e,
            ModbusPostError::Overflow {
                index: 0,
                axis: "Y",
                value: 3_000_000.0
            }
        );
        assert!(e.to_string().starts_with("move 0: Y = 3000000 mm"), "{e}");
    }

    #[test]
    fn a_tool_change_is_a_tool_block_in_place_with_the_tool_number() {
        let mut tp = Toolpath::new("t");
        tp.push(Move::ToolChange {
            tool: 1,
            name: "3 mm drill".into(),
            geometry: None,
        });
        tp.push(Move::Rapid {
            to: P3::new(10.0, 5.0, 2.0),
        });
        tp.push(Move::ToolChange {
            tool: 2,
            name: String::new(),
            geometry: None,
        });
        tp.push(Move::Linear {
            to: P3::new(10.0, 5.0, -1.0),
            feed: 300.0,
        });
        let b = post_blocks(&tp).unwrap();
        let kinds: Vec<BlockKind> = b.iter().map(|b| b.kind).collect();
        assert_eq!(
            kinds,
            [
                BlockKind::ToolChange,
                BlockKind::Rapid,
                BlockKind::ToolChange,
                BlockKind::Linear,
                BlockKind::End
            ]
        );
        assert_eq!((b[0].feed, b[0].target), (1, [0, 0, 0]));
        assert_eq!((b[2].feed, b[2].target), (2, [10_000, 5_000, 2_000]));
        assert_eq!(b[2].to_string(), "tool T2");
        // the registers: move type 7, the tool in the feed field, I and J 0
        let r = b[2].encode(3, super::super::map::WordOrder::HighFirst);
        assert_eq!(r[2], 7);
        assert_eq!(&r[10..12], &[0, 2]);
        assert_eq!(
            MotionBlock::decode(&r, super::super::map::WordOrder::HighFirst),
            Ok((3, b[2]))
        );
    }
}
