//! The job options of `plan`, `submit`, `preview` and `demo` as command-line flags, turned
//! into the one `JobSpec` the intake takes. Every default is the operation's own (offset-core
//! `Default`), so a flag left out here means what a key left out of a JSON job means.

use machlink::core::intake::{Input, JobSpec, Operation};
use offset_core::mesh::{Cutter, CutterShape, Finish3dParams, Rough3dParams, WaterlineParams};
use offset_core::ops::{
    AdaptiveParams, Cutting, Entry, PocketParams, ProfileParams, Side, Stepover,
};
use offset_core::stitch::StitchParams;
use offset_core::Tool;
use std::path::Path;

/// The operation to plan.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Op {
    /// Cut along the outline (see --side).
    Profile,
    /// Clear the inside of closed shapes, around their islands.
    Pocket,
    /// Clear the inside of closed shapes keeping the tool's engagement at or under
    /// --engagement (adaptive clearing; the bound is not yet held everywhere:
    /// docs/toolpaths.md).
    Adaptive,
    /// Sew stitches along the shape (sewing machines).
    Stitch,
    /// Drill the circles the tool's size (see --cycle); bore larger ones with a helix.
    Drill,
    /// 3D: clear a mesh (.stl) or point grid (.csv) level by level, leaving --stock-allowance.
    Rough3d,
    /// 3D: raster finishing with a drop cutter (--cutter ball|flat|bull), gouge-free.
    Finish3d,
    /// 3D: waterline contours with a ball, flat or bull cutter (--cutter).
    Waterline,
}

/// How the tool enters material.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum EntryArg {
    Plunge,
    Ramp,
    Helix,
}

/// The end of a 3D cutter.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum CutterArg {
    Ball,
    Flat,
    Bull,
}

/// A drilling cycle.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum CycleArg {
    /// Feed to depth, rapid out (G81).
    Simple,
    /// Feed to depth, dwell --dwell seconds, rapid out (G82).
    Dwell,
    /// Feed down --peck mm at a time, rapid out after each (G83).
    Peck,
}

/// Side of the outline for a profile.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum SideArg {
    Outside,
    Inside,
    On,
}

/// The options of a job. Left out, each takes the operation's default (shown in brackets).
#[derive(Clone, Debug, Default, clap::Args)]
pub struct JobArgs {
    /// The operation (not for a G-code file, which runs as it is).
    #[arg(long, value_enum)]
    pub op: Option<Op>,
    /// A job of several operations: a recipe file (TOML, `[[operations]]` each with its
    /// `op`, `tool` and the geometry it `take`s; see docs/toolpaths.md), instead of --op.
    #[arg(long, visible_alias = "ops", value_name = "RECIPE.toml")]
    pub recipe: Option<std::path::PathBuf>,
    /// Cutter diameter, mm [3; 3D: 6].
    #[arg(long)]
    pub tool_diameter: Option<f64>,
    /// How far below the stock top (Z=0) the last pass cuts, mm [1].
    #[arg(long)]
    pub depth: Option<f64>,
    /// The most each depth pass goes down, mm [1].
    #[arg(long)]
    pub stepdown: Option<f64>,
    /// Profile: which side of the outline the tool runs on [outside]. Outside and inside
    /// need closed contours (open ones are refused alone, warned about beside closed ones).
    #[arg(long, value_enum)]
    pub side: Option<SideArg>,
    /// Cutting feed, mm/min [800].
    #[arg(long)]
    pub feed: Option<f64>,
    /// Plunge feed, mm/min [300].
    #[arg(long)]
    pub plunge_feed: Option<f64>,
    /// Height for rapid moves above the stock, mm [5].
    #[arg(long)]
    pub safe_z: Option<f64>,
    /// Spindle speed, rpm (0: leave the spindle alone) [12000].
    #[arg(long)]
    pub spindle: Option<f64>,
    /// Cut conventional instead of climb (for an M3 spindle).
    #[arg(long)]
    pub conventional: bool,
    /// How the tool goes down into material: a helix where one fits, else a ramp along
    /// the pass, else straight down with a warning [helix].
    #[arg(long, value_enum)]
    pub entry: Option<EntryArg>,
    /// The steepest a ramp or helix descends, degrees from the horizontal [3].
    #[arg(long)]
    pub ramp_angle: Option<f64>,
    /// Diameter of a helix entry, mm (0: the tool diameter, shrunk to half where there
    /// is no room) [0].
    #[arg(long)]
    pub helix_diameter: Option<f64>,
    /// Profile: go down the depth passes of a closed loop in one unbroken helix.
    #[arg(long)]
    pub spiral: bool,
    /// Geometric tolerance of every approximation (reading curves, offsets), mm [0.001].
    #[arg(long)]
    pub tolerance: Option<f64>,
    /// Pocket: distance between neighbouring passes, mm (1.2) or a percentage of the tool
    /// diameter (40%); at most the diameter [40%].
    #[arg(long, value_parser = parse_stepover)]
    pub stepover: Option<Stepover>,
    /// Pocket: scale each cut's feed to the simulated engagement so the chip stays as thick
    /// as the feed makes it at the step-over, up to --max-feed (docs/toolpaths.md).
    #[arg(long)]
    pub feed_control: bool,
    /// Adaptive: the largest angle of the tool's circumference in the material, degrees
    /// (10 to 180) [70].
    #[arg(long, value_name = "DEG")]
    pub engagement: Option<f64>,
    /// Adaptive: leave 2 % of the tool diameter on the walls and take it in one last pass
    /// round each wall at the full depth.
    #[arg(long)]
    pub finish_pass: bool,
    /// Feed control: the largest feed the machine runs, mm/min [5000].
    #[arg(long)]
    pub max_feed: Option<f64>,

    /// Drill: the cycle [simple].
    #[arg(long, value_enum)]
    pub cycle: Option<CycleArg>,
    /// Drill: how far each peck goes down, mm [1].
    #[arg(long)]
    pub peck: Option<f64>,
    /// Drill: seconds at the bottom of a dwell cycle [0.5].
    #[arg(long)]
    pub dwell: Option<f64>,
    /// Drill: refuse circles larger than the tool instead of boring them.
    #[arg(long)]
    pub no_bore: bool,
    /// Profile: holding tabs per closed loop, evenly spaced [0].
    #[arg(long)]
    pub tabs: Option<usize>,
    /// Profile: width of the material each tab leaves, mm [3].
    #[arg(long)]
    pub tab_width: Option<f64>,
    /// Profile: height of the tabs above the bottom of the cut, mm [0.5].
    #[arg(long)]
    pub tab_height: Option<f64>,
    /// Profile: radius of the tangent lead-in arc onto each closed loop, on the side away
    /// from the part, mm (0: start on the loop) [0].
    #[arg(long)]
    pub lead_in: Option<f64>,
    /// Profile: radius of the tangent lead-out arc, mm [the lead-in radius].
    #[arg(long)]
    pub lead_out: Option<f64>,
    /// DXF: read only the entities on this layer (repeat for several) [all layers].
    #[arg(long)]
    pub layer: Vec<String>,
    /// Stitch: nominal stitch length, mm (1 to 12.7); each run between corners gets equal
    /// stitches [2.5].
    #[arg(long)]
    pub stitch_length: Option<f64>,
    /// Stitch: rows to sew as offsets from each curve, mm, comma separated (0 = on the
    /// curve; closed curves: negative inside; open curves: positive left) [0].
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    pub rows: Option<Vec<f64>>,
    /// Stitch: bean stitch (each stitch sewn forward, back, forward).
    #[arg(long)]
    pub bean: bool,
    /// Stitch: tie-in and tie-off stitches at the start and end of each seam [on].
    #[arg(long, overrides_with = "no_tie")]
    pub tie: bool,
    /// Stitch: no tie stitches.
    #[arg(long)]
    pub no_tie: bool,
    /// Stitch: a turn sharper than this many degrees is a corner with a needle drop on it [20].
    #[arg(long)]
    pub corner_angle: Option<f64>,
    /// Stitch: round the corners of offset rows instead of keeping them sharp.
    #[arg(long)]
    pub round_corners: bool,
    /// Stitch: how far a stitch may stray from its curve, mm (at least 0.1) [0.2].
    #[arg(long)]
    pub stitch_tolerance: Option<f64>,
    /// 3D finishing: the cutter's end [ball].
    #[arg(long, value_enum)]
    pub cutter: Option<CutterArg>,
    /// 3D: a bull cutter's corner radius, mm [1].
    #[arg(long)]
    pub corner_radius: Option<f64>,
    /// 3D roughing: material left on the part for finishing, mm [0.3].
    #[arg(long)]
    pub stock_allowance: Option<f64>,
    /// 3D: the stock top, Z in the mesh's frame [the mesh's highest Z].
    #[arg(long, allow_hyphen_values = true)]
    pub stock_top: Option<f64>,
    /// 3D: the lowest Z to cut to [the mesh's lowest Z].
    #[arg(long, allow_hyphen_values = true)]
    pub floor: Option<f64>,
    /// 3D roughing: how far the stock reaches beyond the part's outline, mm [0].
    #[arg(long)]
    pub stock_margin: Option<f64>,
    /// 3D finishing: direction of the raster rows, degrees from +X [0].
    #[arg(long, allow_hyphen_values = true)]
    pub angle: Option<f64>,
    /// 3D finishing: cut every row in the same direction (retract between rows) instead of
    /// zig-zag.
    #[arg(long)]
    pub one_way: bool,
}

fn parse_stepover(s: &str) -> Result<Stepover, String> {
    s.parse()
}

impl JobArgs {
    /// The job for the file at `path` with these options, for machine `machine` (if any)
    /// written with `post` (if any).
    pub fn spec(
        &self,
        path: &Path,
        machine: Option<String>,
        post: Option<String>,
    ) -> anyhow::Result<JobSpec> {
        let operations = match &self.recipe {
            None => Vec::new(),
            Some(_) if self.op.is_some() => {
                anyhow::bail!("give either --op or --recipe (--ops), not both")
            }
            Some(file) => machlink::core::intake::recipe::Recipe::from_path(file)?.operations,
        };
        Ok(JobSpec {
            machine,
            input: Input::from_path(path)?,
            operation: self.operation(),
            operations,
            tolerance: self.tolerance,
            layers: self.layer.clone(),
            post,
        })
    }

    /// The operation with its options, or none when no `--op` was given.
    pub fn operation(&self) -> Option<Operation> {
        Some(match self.op? {
            Op::Profile => {
                let d = ProfileParams::default();
                let lead_in = self.lead_in.unwrap_or(d.lead_in);
                Operation::Profile(ProfileParams {
                    side: match self.side {
                        None => d.side,
                        Some(SideArg::Outside) => Side::Outside,
                        Some(SideArg::Inside) => Side::Inside,
                        Some(SideArg::On) => Side::On,
                    },
                    cut: self.cutting(d.cut),
                    lead_in,
                    lead_out: self.lead_out.unwrap_or(lead_in),
                    tabs: self.tabs.unwrap_or(d.tabs),
                    tab_width: self.tab_width.unwrap_or(d.tab_width),
                    tab_height: self.tab_height.unwrap_or(d.tab_height),
                })
            }
            Op::Pocket => {
                let d = PocketParams::default();
                let pocket = PocketParams {
                    cut: self.cutting(d.cut),
                    stepover: self.stepover.unwrap_or(d.stepover),
                };
                if self.feed_control {
                    let f = offset_core::cutsim::feed::FeedControl::default();
                    Operation::PocketFeedControl(offset_core::cutsim::feed::FeedControlledPocket {
                        pocket,
                        feed_control: offset_core::cutsim::feed::FeedControl {
                            max_feed: self.max_feed.unwrap_or(f.max_feed),
                            ..f
                        },
                    })
                } else {
                    Operation::Pocket(pocket)
                }
            }
            Op::Adaptive => {
                let d = AdaptiveParams::default();
                Operation::Adaptive(AdaptiveParams {
                    cut: self.cutting(d.cut),
                    engagement: self.engagement.unwrap_or(d.engagement),
                    finish: self.finish_pass || d.finish,
                    ..d
                })
            }
            Op::Stitch => {
                let d = StitchParams::default();
                Operation::Stitch(StitchParams {
                    stitch_length: self.stitch_length.unwrap_or(d.stitch_length),
                    rows: self.rows.clone().unwrap_or(d.rows),
                    bean: self.bean || d.bean,
                    tie: if self.no_tie {
                        false
                    } else {
                        self.tie || d.tie
                    },
                    corner_angle: self.corner_angle.unwrap_or(d.corner_angle),
                    round_corners: self.round_corners || d.round_corners,
                    tolerance: self.stitch_tolerance.unwrap_or(d.tolerance),
                    ..d
                })
            }
            Op::Drill => {
                let d = offset_core::ops::DrillParams::default();
                Operation::Drill(offset_core::ops::DrillParams {
                    tool: Tool {
                        diameter: self.tool_diameter.unwrap_or(d.tool.diameter),
                        ..d.tool
                    },
                    depth: self.depth.unwrap_or(d.depth),
                    cycle: match self.cycle {
                        None => d.cycle,
                        Some(CycleArg::Simple) => offset_core::ops::Cycle::Simple,
                        Some(CycleArg::Dwell) => offset_core::ops::Cycle::Dwell,
                        Some(CycleArg::Peck) => offset_core::ops::Cycle::Peck,
                    },
                    peck: self.peck.unwrap_or(d.peck),
                    dwell: self.dwell.unwrap_or(d.dwell),
                    feed: self.plunge_feed.unwrap_or(d.feed),
                    bore_feed: self.feed.unwrap_or(d.bore_feed),
                    stepdown: self.stepdown.unwrap_or(d.stepdown),
                    safe_z: self.safe_z.unwrap_or(d.safe_z),
                    spindle_rpm: self.spindle.unwrap_or(d.spindle_rpm),
                    bore: !self.no_bore && d.bore,
                    ..d
                })
            }
            Op::Rough3d => {
                let d = Rough3dParams::default();
                Operation::Rough3d(Rough3dParams {
                    tool: Tool {
                        diameter: self.tool_diameter.unwrap_or(d.tool.diameter),
                        ..d.tool
                    },
                    stepdown: self.stepdown.unwrap_or(d.stepdown),
                    stepover: self.stepover.unwrap_or(d.stepover),
                    stock_allowance: self.stock_allowance.unwrap_or(d.stock_allowance),
                    stock_top: self.stock_top.or(d.stock_top),
                    floor: self.floor.or(d.floor),
                    stock_margin: self.stock_margin.unwrap_or(d.stock_margin),
                    feed: self.feed.unwrap_or(d.feed),
                    plunge_feed: self.plunge_feed.unwrap_or(d.plunge_feed),
                    safe_z: self.safe_z.unwrap_or(d.safe_z),
                    climb: !self.conventional && d.climb,
                    spindle_rpm: self.spindle.unwrap_or(d.spindle_rpm),
                    tolerance: self.tolerance.unwrap_or(d.tolerance),
                })
            }
            Op::Finish3d => {
                let d = Finish3dParams::default();
                Operation::Finish3d(Finish3dParams {
                    cutter: self.cutter_over(d.cutter),
                    stepover: self.stepover.unwrap_or(d.stepover),
                    angle: self.angle.unwrap_or(d.angle),
                    tolerance: self.tolerance.unwrap_or(d.tolerance),
                    feed: self.feed.unwrap_or(d.feed),
                    plunge_feed: self.plunge_feed.unwrap_or(d.plunge_feed),
                    safe_z: self.safe_z.unwrap_or(d.safe_z),
                    stock_top: self.stock_top.or(d.stock_top),
                    spindle_rpm: self.spindle.unwrap_or(d.spindle_rpm),
                    zigzag: !self.one_way && d.zigzag,
                    floor: self.floor.or(d.floor),
                    ..d
                })
            }
            Op::Waterline => {
                let d = WaterlineParams::default();
                Operation::Waterline(WaterlineParams {
                    cutter: self.cutter_over(d.cutter),
                    stepdown: self.stepdown.unwrap_or(d.stepdown),
                    tolerance: self.tolerance.unwrap_or(d.tolerance),
                    feed: self.feed.unwrap_or(d.feed),
                    plunge_feed: self.plunge_feed.unwrap_or(d.plunge_feed),
                    safe_z: self.safe_z.unwrap_or(d.safe_z),
                    stock_top: self.stock_top.or(d.stock_top),
                    floor: self.floor.or(d.floor),
                    spindle_rpm: self.spindle.unwrap_or(d.spindle_rpm),
                    climb: !self.conventional && d.climb,
                    ..d
                })
            }
        })
    }

    /// A 3D cutter from the flags over the operation's default cutter.
    fn cutter_over(&self, d: Cutter) -> Cutter {
        let shape = match self.cutter {
            None => d.shape,
            Some(CutterArg::Ball) => CutterShape::Ball,
            Some(CutterArg::Flat) => CutterShape::Flat,
            Some(CutterArg::Bull) => CutterShape::Bull,
        };
        let corner = match (self.corner_radius, shape) {
            (Some(r), _) => r,
            (None, CutterShape::Bull) if d.corner_radius == 0.0 => 1.0,
            (None, _) => d.corner_radius,
        };
        Cutter {
            shape,
            diameter: self.tool_diameter.unwrap_or(d.diameter),
            corner_radius: corner,
        }
    }

    /// The tool, depths, feeds and heights from the flags over the operation's defaults.
    fn cutting(&self, d: Cutting) -> Cutting {
        Cutting {
            tool: Tool {
                diameter: self.tool_diameter.unwrap_or(d.tool.diameter),
                ..d.tool
            },
            depth: self.depth.unwrap_or(d.depth),
            stepdown: self.stepdown.unwrap_or(d.stepdown),
            feed: self.feed.unwrap_or(d.feed),
            plunge_feed: self.plunge_feed.unwrap_or(d.plunge_feed),
            safe_z: self.safe_z.unwrap_or(d.safe_z),
            climb: !self.conventional && d.climb,
            spindle_rpm: self.spindle.unwrap_or(d.spindle_rpm),
            tolerance: self.tolerance.unwrap_or(d.tolerance),
            entry: match self.entry {
                None => d.entry,
                Some(EntryArg::Plunge) => Entry::Plunge,
                Some(EntryArg::Ramp) => Entry::Ramp,
                Some(EntryArg::Helix) => Entry::Helix,
            },
            ramp_angle: self.ramp_angle.unwrap_or(d.ramp_angle),
            helix_diameter: self.helix_diameter.unwrap_or(d.helix_diameter),
            spiral: self.spiral || d.spiral,
        }
    }
}

/// Prints the readers' and planners' warnings.
pub fn print_warnings(warnings: &[String]) {
    for w in warnings {
        eprintln!("machlink: warning: {w}");
    }
}
