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
    /// Tajima DST embroidery file (stitch operation).
    Dst,
    /// Janome JEF embroidery file (stitch operation).
    Jef,
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
    /// The stitch operation's options.
    #[command(flatten)]
    #[serde(flatten, default)]
    pub stitch: StitchArgs,
}

/// The options of the stitch operation (`--op stitch`); each may be left out of a JSON
/// submission (its default applies).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, clap::Args)]
#[serde(default)]
pub struct StitchArgs {
    /// Stitch: nominal stitch length, mm (1 to 12.7); each run between corners gets equal stitches.
    #[arg(long, default_value_t = 2.5)]
    pub stitch_length: f64,
    /// Stitch: rows to sew as offsets from each curve, mm, comma separated (0 = on the curve;
    /// closed curves: negative inside, positive outside; open curves: positive left).
    #[arg(
        long,
        value_delimiter = ',',
        allow_hyphen_values = true,
        default_value = "0"
    )]
    pub rows: Vec<f64>,
    /// Stitch: bean stitch (each stitch sewn forward, back, forward).
    #[arg(long)]
    pub bean: bool,
    /// Stitch: tie-in and tie-off stitches at the start and end of each seam.
    #[arg(long)]
    pub tie: bool,
    /// Stitch: a turn sharper than this many degrees is a corner and gets a needle drop on it.
    #[arg(long, default_value_t = 20.0)]
    pub corner_angle: f64,
    /// Stitch: round the corners of offset rows instead of keeping them sharp.
    #[arg(long)]
    pub round_corners: bool,
    /// Stitch: how far a stitch may stray from its curve, mm (at least 0.1).
    #[arg(long, default_value_t = 0.2)]
    pub stitch_tolerance: f64,
}

impl Default for StitchArgs {
    fn default() -> Self {
        StitchArgs {
            stitch_length: 2.5,
            rows: vec![0.0],
            bean: false,
            tie: false,
            corner_angle: 20.0,
            round_corners: false,
            stitch_tolerance: 0.2,
        }
    }
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
        Op::Stitch => {
            let a = &params.stitch;
            let p = offset_core::stitch::StitchParams {
                stitch_length: a.stitch_length,
                rows: a.rows.clone(),
                bean: a.bean,
                tie: a.tie,
                corner_angle: a.corner_angle,
                round_corners: a.round_corners,
                tolerance: a.stitch_tolerance,
                ..Default::default()
            };
            Ok(offset_core::stitch::stitch(shape, &p).context("cannot plan the stitches")?)
        }
    }
}

/// Turns a tool path into the program for `post`.
pub fn post(tp: &Toolpath, post: Post) -> anyhow::Result<Program> {
    use machlink_protocols::sewing::{self, RecordLimits};
    let dialect = match post {
        Post::Grbl => Dialect::Grbl,
        Post::Linuxcnc => Dialect::Linuxcnc,
        Post::Generic => Dialect::Generic,
        Post::Dst => {
            return sewing::post(tp, RecordLimits::DST).context("cannot write the DST stitches")
        }
        Post::Jef => {
            return sewing::post(tp, RecordLimits::JEF).context("cannot write the JEF stitches")
        }
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
