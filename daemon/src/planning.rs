//! Planning: shape + operation + post → program. Shared by `machlink plan` (offline) and
//! `machlink submit` (queued on a machine), so both make the same program from the same input.

use anyhow::Context;
use machlink_protocols::gcode::{self, Dialect, GcodeOptions};
use machlink_protocols::Program;
use offset_core::ops::{pocket, profile, PocketParams, ProfileParams, Side, Stepover};
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
    /// Pocket: distance between neighbouring passes, in mm (1.2) or as a percentage of the
    /// tool diameter (40%); at most the diameter.
    #[arg(long, default_value = "40%", value_parser = parse_stepover)]
    #[serde(default = "default_stepover")]
    pub stepover: Stepover,
    /// Profile: holding tabs per closed loop, evenly spaced (0: none).
    #[arg(long, default_value_t = 0)]
    #[serde(default)]
    pub tabs: usize,
    /// Profile: width of the material each tab leaves, mm.
    #[arg(long, default_value_t = 3.0)]
    #[serde(default)]
    pub tab_width: f64,
    /// Profile: height of the tabs above the bottom of the cut, mm.
    #[arg(long, default_value_t = 0.5)]
    #[serde(default)]
    pub tab_height: f64,
    /// Profile: radius of the tangent lead-in arc onto each closed loop, on the side away
    /// from the part, mm (0: plunge on the loop).
    #[arg(long, default_value_t = 0.0)]
    #[serde(default)]
    pub lead_in: f64,
    /// Profile: radius of the tangent lead-out arc, mm (default: the lead-in radius).
    #[arg(long)]
    #[serde(default)]
    pub lead_out: Option<f64>,
    /// DXF: read only the entities on this layer (repeat for several; default: all layers).
    #[arg(long)]
    #[serde(default)]
    pub layer: Vec<String>,
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

fn default_stepover() -> Stepover {
    Stepover::Percent(40.0)
}

/// Parses a step-over: `1.2` (mm) or `40%` (of the tool diameter).
fn parse_stepover(s: &str) -> Result<Stepover, String> {
    s.parse()
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

impl PlanParams {
    /// The options for `op` with every other option at its command-line default, so that
    /// code that builds parameters (the demo, tests) plans what `machlink plan --op OP` would.
    pub fn defaults(op: Op) -> PlanParams {
        use clap::Parser;
        #[derive(clap::Parser)]
        struct P {
            #[command(flatten)]
            p: PlanParams,
        }
        let op = clap::ValueEnum::to_possible_value(&op).expect("every op has a name");
        P::parse_from(["machlink", "--op", op.get_name()]).p
    }
}

/// The tool, depths, feeds and heights of a milling operation, from the options.
fn cutting(params: &PlanParams) -> offset_core::ops::Cutting {
    offset_core::ops::Cutting {
        tool: Tool::flat(params.tool_diameter),
        depth: params.depth,
        stepdown: params.stepdown,
        feed: params.feed,
        plunge_feed: params.plunge_feed,
        safe_z: params.safe_z,
        climb: !params.conventional,
        spindle_rpm: params.spindle,
        tolerance: params.tolerance,
        ..Default::default() // entries (helix, ramp angle, spiral): offset-core's defaults
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
                lead_in: params.lead_in,
                lead_out: params.lead_out.unwrap_or(params.lead_in),
                tabs: params.tabs,
                tab_width: params.tab_width,
                tab_height: params.tab_height,
                cut: cutting(params),
            };
            Ok(profile(shape, &p).context("cannot plan the profile")?)
        }
        Op::Pocket => {
            let p = PocketParams {
                stepover: params.stepover,
                cut: cutting(params),
            };
            Ok(pocket(shape, &p).context("cannot plan the pocket")?)
        }
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
        Post::Modbus => {
            return machlink_protocols::modbus::post(tp).context("cannot make Modbus motion blocks")
        }
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

/// Reads a shape file from disk with the layers and tolerance of `params`; the readers'
/// warnings (open contours, gaps, crossings, skipped entities) go to stderr.
pub fn read_shape_for(path: &std::path::Path, params: &PlanParams) -> anyhow::Result<Shape> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let file = path.display().to_string();
    let (shape, warnings) = offset_core::io::read_shape_with(
        &bytes,
        &file,
        &offset_core::io::ReadOptions {
            layers: params.layer.clone(),
            tolerance: params.tolerance,
        },
    )?;
    for w in warnings {
        eprintln!("machlink: warning: {file}: {w}");
    }
    Ok(shape)
}

/// Reads a shape file from disk, naming the file in every error.
#[allow(dead_code)] // the plain reader, for callers without plan options
pub fn read_shape(path: &std::path::Path) -> anyhow::Result<Shape> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    Ok(offset_core::io::read_shape(
        &bytes,
        &path.display().to_string(),
    )?)
}
