//! Programs: what a post makes from a tool path and a link sends, unit by unit.

use serde::{Deserialize, Serialize};

/// An ordered list of units that the device acknowledges one by one. Progress is counted
/// in units; the last acknowledged unit is where a resume starts.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", content = "units", rename_all = "snake_case")]
pub enum Program {
    /// G-code lines, without line endings, comments or bytes >= 0x80.
    Gcode(Vec<String>),
    /// Stitch records for a pattern sewing machine (absolute, 0.1 mm): one unit per record.
    Stitches(Vec<crate::sewing::StitchRecord>),
    /// Motion blocks for a Modbus ring buffer; block `i` travels as sequence `i + 1`.
    Modbus(Vec<crate::modbus::MotionBlock>),
}

impl Program {
    /// How many units the program has.
    pub fn len(&self) -> usize {
        match self {
            Program::Gcode(lines) => lines.len(),
            Program::Stitches(records) => records.len(),
            Program::Modbus(blocks) => blocks.len(),
        }
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// A short name of the program's kind, for messages and the store.
    pub fn kind(&self) -> &'static str {
        match self {
            Program::Gcode(_) => "gcode",
            Program::Stitches(_) => "stitches",
            Program::Modbus(_) => "modbus",
        }
    }
    /// Unit `i` as text, for messages (a G-code line as it is).
    pub fn describe_unit(&self, i: usize) -> String {
        match self {
            Program::Gcode(lines) => lines.get(i).cloned().unwrap_or_default(),
            Program::Stitches(records) => records
                .get(i)
                .map(|r| format!("{:?} at ({:.1}, {:.1}) mm", r.kind, r.mm().x, r.mm().y))
                .unwrap_or_default(),
            Program::Modbus(blocks) => blocks.get(i).map(|b| b.to_string()).unwrap_or_default(),
        }
    }
}
