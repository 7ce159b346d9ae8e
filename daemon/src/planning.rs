//! Planning: shape + operation + post → program. Shared by `machlink plan` (offline) and
//! `machlink submit` (queued on a machine), so both make the same program from the same input.

use anyhow::Context;
use machlink_protocols::gcode::{self, Dialect, GcodeOptions};
use machlink_protocols::Program;
use offset_core::ops::{profile, ProfileParams, Side};
use offset_core::{Shape, Tool, Toolpath};
use serde::{Deserialize, Serialize};

/// The operation to plan.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Op {
    /// Cut along the outline (see --side).
    Profile,
    /// Clear the inside of closed shapes, around their islands.
    Pocket,
    /// Sew stitches along the shape (sewing machines).
    Stitch,
}

/// The program format to write.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Post {
    Grbl,
    Linuxcnc,
    Generic,
    /// Motion blocks for a Modbus ring buffer (docs/modbus.md).
    Modbus,
}

/// Side of the outline for a profile (mirrors offset_core's Side for the command line).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum SideArg {
    Outside,
    Inside,
    On,
}

/// Everything an operation needs besides the shape. The same options serve `plan` and
/// `submit`; `submit` sends them to the daemon as JSON.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, clap::Args)]
pub struct PlanParams {
    /// The operation.
    #[arg(long, value_enum)]
    pub op: Op,
    /// Cutter diameter, mm.
    #[arg(long, default_value_t = 3.0)]
    pub tool_diameter: f64,
    /// How far below the stock top (Z=0) the last pass cuts, mm.
    #[arg(long, default_value_t = 1.0)]
    pub depth: f64,
    /// The most each depth pass goes down, mm.
    #[arg(long, default_value_t = 1.0)]
    pub stepdown: f64,
    /// Which side of the outline a profile cuts on.
    #[arg(long, value_enum, default_value = "outside")]
    pub side: SideArg,
    /// Cutting feed, mm/min.
    #[arg(long, default_value_t = 800.0)]
    pub feed: f64,
    /// Plunge feed, mm/min.
    #[arg(long, default_value_t = 300.0)]
    pub plunge_feed: f64,
    /// Height for rapid moves above the stock, mm.
    #[arg(long, default_value_t = 5.0)]
    pub safe_z: f64,
    /// Spindle speed, rpm (0: leave the spindle alone).
    #[arg(long, default_value_t = 12000.0)]
    pub spindle: f64,
    /// Cut conventional instead of climb (for an M3 spindle).
    #[arg(long)]
    pub conventional: bool,
    /// Geometric tolerance of every approximation, mm.
    #[arg(long, default_value_t = 0.001)]
    pub tolerance: f64,
}

/// Plans the tool path of `params.op` on `shape`.
pub fn plan_toolpath(shape: &Shape, params: &PlanParams) -> anyhow::Result<Toolpath> {
    match params.op {
        Op::Profile => {
            let p = ProfileParams {
                side: match params.side {
                    SideArg::Outside => Side::Outside,
                    SideArg::Inside => Side::Inside,
                    SideArg::On => Side::On,
                },
                tool: Tool::flat(params.tool_diameter),
                depth: params.depth,
                stepdown: params.stepdown,
                feed: params.feed,
                plunge_feed: params.plunge_feed,
                safe_z: params.safe_z,
                climb: !params.conventional,
                spindle_rpm: params.spindle,
                tolerance: params.tolerance,
            };
            Ok(profile(shape, &p).context("cannot plan the profile")?)
        }
        Op::Pocket => anyhow::bail!("the pocket operation is not built yet"),
        Op::Stitch => anyhow::bail!("the stitch operation is not built yet"),
    }
}

/// Turns a tool path into the program for `post`.
pub fn post(tp: &Toolpath, post: Post) -> anyhow::Result<Program> {
    let dialect = match post {
        Post::Modbus => {
            return machlink_protocols::modbus::post(tp).context("cannot make Modbus motion blocks")
        }
        Post::Grbl => Dialect::Grbl,
        Post::Linuxcnc => Dialect::Linuxcnc,
        Post::Generic => Dialect::Generic,
    };
    #[allow(clippy::needless_update)] // the post grows options; they keep their defaults here
    let opts = GcodeOptions {
        dialect,
        ..Default::default()
    };
    gcode::post(tp, &opts).context("cannot write the G-code")
}

/// Reads a shape file from disk, naming the file in every error.
pub fn read_shape(path: &std::path::Path) -> anyhow::Result<Shape> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    Ok(offset_core::io::read_shape(
        &bytes,
        &path.display().to_string(),
    )?)
}
