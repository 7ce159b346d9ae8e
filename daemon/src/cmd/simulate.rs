//! `machlink simulate`: replay a G-code program (or a job planned from a shape, as `plan`
//! plans it) against the stock and tell the operator what the tool goes through: the worst
//! engagement, the longest cut in air, the removal rate over time, gouges and material
//! left; and draw the engagement along the path (offset_core::cutsim).

use super::job::{print_warnings, JobArgs};
use anyhow::{bail, Context};
use machlink::core::intake::{self, Input, InputKind, JobSpec};
use offset_core::cutsim::{self, MoveKind, Part, Report, SimOptions, Stock};
use offset_core::geom::{Point, Region};
use offset_core::{Tool, Toolpath};
use std::path::{Path, PathBuf};

#[derive(clap::Args)]
pub struct SimulateArgs {
    /// A G-code program (.nc, .gcode, .ngc, .tap), or a shape file (.json, .dxf, .svg)
    /// with --op to plan first.
    pub file: PathBuf,
    /// The stock: a box `X0,Y0,X1,Y1` in mm, or a shape file whose closed outlines it
    /// fills [a planned job: the shape's extent].
    #[arg(long, allow_hyphen_values = true)]
    pub stock: Option<String>,
    /// Z of the stock's top, mm [0].
    #[arg(long, allow_hyphen_values = true, default_value_t = 0.0)]
    pub stock_z: f64,
    /// Diameter of the flat end mill the program runs, mm [a planned job: its tool].
    #[arg(long)]
    pub tool: Option<f64>,
    /// The part: a shape file whose regions the program clears down to --depth (pockets);
    /// the stock elsewhere is the part. With it, gouges and material left are reported
    /// [a planned pocket: its shape].
    #[arg(long)]
    pub part: Option<PathBuf>,
    /// Side of a simulation cell, mm [the tool diameter / 120].
    #[arg(long)]
    pub cell: Option<f64>,
    /// Draw the engagement along the path here (.svg or .png).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Width of the drawing in pixels.
    #[arg(long, default_value_t = 1000)]
    pub width: u32,
    /// Print the whole report (every move) as JSON on stdout instead of the summary.
    #[arg(long)]
    pub json: bool,
    /// Plan options, as for `machlink plan`, when FILE is a shape.
    #[command(flatten)]
    pub job: JobArgs,
}

pub fn run(a: SimulateArgs) -> anyhow::Result<()> {
    let input = Input::from_path(&a.file)?;
    let (tp, lines, planned_shape, op) = match input.kind() {
        InputKind::Gcode => {
            let text = String::from_utf8(input.bytes()?)
                .with_context(|| format!("{} is not a text file", a.file.display()))?;
            let (tp, lines) = machlink_protocols::gcode_read::read_with_lines(&text)
                .with_context(|| format!("{} is not G-code we can simulate", a.file.display()))?;
            (tp, Some(lines), None, None)
        }
        InputKind::Shape => {
            let spec = JobSpec {
                post: None,
                ..a.job.spec(&a.file, None, None)?
            };
            if spec.operation.is_none() {
                bail!(
                    "{} is a shape file: say which operation to plan and simulate (--op pocket, profile, …) or give a G-code program",
                    a.file.display()
                );
            }
            let (shape, warnings) = intake::read_shape(&spec)?;
            print_warnings(&warnings);
            let tp = intake::toolpath(&spec, &shape)?;
            let op = spec.operation.as_ref().map(|o| o.name().to_string());
            (tp, None, Some(shape), op)
        }
        _ => bail!(
            "{} is a mesh or point grid: simulate takes 2.5D work (a G-code program or a shape with --op)",
            a.file.display()
        ),
    };
    let diameter = match (a.tool, tp.tool) {
        (Some(d), _) => d,
        (None, Some(t)) => t.diameter,
        (None, None) => bail!(
            "say which tool {} runs: --tool DIAMETER (mm)",
            a.file.display()
        ),
    };
    if !(diameter.is_finite() && diameter > 0.0) {
        bail!("--tool must be a diameter above 0 mm, got {diameter}");
    }
    let stock = match (&a.stock, &planned_shape) {
        (Some(s), _) => read_stock(s, a.stock_z, &a.job)?,
        (None, Some(shape)) => {
            let b = shape.bounds();
            Stock::block(b.min, b.max, a.stock_z)
        }
        (None, None) => bail!(
            "say where the stock is: --stock X0,Y0,X1,Y1 (mm) or --stock FILE (its closed outlines)"
        ),
    };
    let depth = a
        .job
        .depth
        .unwrap_or(offset_core::ops::Cutting::default().depth);
    let part = match (&a.part, &planned_shape, op.as_deref()) {
        (Some(p), _, _) => Some(Part {
            clear: regions_of(p, &a.job)?,
            floor: a.stock_z - depth,
        }),
        (None, Some(shape), Some("pocket" | "adaptive")) => Some(Part {
            clear: shape.regions(),
            floor: a.stock_z - depth,
        }),
        _ => None,
    };
    let mut o = SimOptions::new(Tool::flat(diameter));
    if let Some(c) = a.cell {
        if !(c.is_finite() && c > 0.0) {
            bail!("--cell must be a length above 0 mm, got {c}");
        }
        o.cell = c;
    }
    o.part = part;
    let rep = cutsim::simulate(&tp, &stock, &o)?;
    if a.json {
        super::out(&serde_json::to_string_pretty(&rep)?)?;
        super::out("\n")?;
    } else {
        super::out(&summary(&rep, &tp, lines.as_deref(), &o))?;
    }
    if let Some(out) = &a.output {
        let clear = o.part.as_ref().map(|p| p.clear.as_slice());
        let svg = cutsim::picture::svg(&rep, &stock, clear, a.width as f64);
        super::preview::write_drawing(out, &svg)?;
        eprintln!("wrote {}", out.display());
    }
    Ok(())
}

/// Where move `index` of the program comes from: its line in the file, or its number.
fn place(index: usize, lines: Option<&[usize]>) -> String {
    match lines.and_then(|l| l.get(index)) {
        Some(line) => format!("line {line}"),
        None => format!("move {}", index + 1),
    }
}

/// The operator's summary of a simulation.
pub fn summary(rep: &Report, tp: &Toolpath, lines: Option<&[usize]>, o: &SimOptions) -> String {
    let mut s = String::new();
    let cutting = rep
        .moves
        .iter()
        .filter(|m| m.kind != MoveKind::Rapid)
        .count();
    s.push_str(&format!(
        "simulated {} moves ({} cutting) of {} with a {} mm flat end mill on {:.3} mm cells\n",
        rep.moves.len(),
        cutting,
        if tp.operation.is_empty() {
            "the program"
        } else {
            &tp.operation
        },
        o.tool.diameter,
        rep.cell
    ));
    let at = |m: &cutsim::MoveReport| {
        format!(
            "{} (X{:.3} Y{:.3} Z{:.3})",
            place(m.index, lines),
            m.to.x,
            m.to.y,
            m.to.z
        )
    };
    // with the part known, the way into each sharp corner of its walls apart: no plan
    // goes in there with less than the corner's turn (cutsim::corner_reading)
    let corners = o
        .part
        .as_ref()
        .map(|p| cutsim::sharp_corners(&p.clear, o.tool.radius()))
        .unwrap_or_default();
    let worst_of = |into: bool| {
        rep.moves
            .iter()
            .filter(|m| m.kind == MoveKind::Cut)
            .filter(|m| cutsim::going_into(&corners, m.to.xy()).is_some() == into)
            .max_by(|a, b| a.engagement.total_cmp(&b.engagement))
    };
    match worst_of(false) {
        Some(m) if corners.is_empty() => s.push_str(&format!(
            "  worst engagement {:.1}° at {}\n",
            m.engagement,
            at(m)
        )),
        Some(m) => s.push_str(&format!(
            "  worst engagement {:.1}° at {} (away from the sharp corners of the walls)\n",
            m.engagement,
            at(m)
        )),
        None => s.push_str("  no cutting move at one depth\n"),
    }
    if let Some(m) = worst_of(true) {
        let turn = cutsim::going_into(&corners, m.to.xy()).unwrap_or(0.0);
        s.push_str(&format!(
            "  going into the {} sharp corners of the walls: worst {:.1}° at {}, where the wall turns by {turn:.0}° (whatever its path, a round tool going into a corner meets material or the part over that turn; on these cells up to {:.1}° reads as that)\n",
            corners.len(),
            m.engagement,
            at(m),
            cutsim::corner_reading(turn, o.tool.radius(), rep.cell)
        ));
    }
    if let Some(m) = rep.worst(&[MoveKind::Entry]) {
        s.push_str(&format!(
            "  worst engagement going down (ramps, helices) {:.1}° at {}\n",
            m.engagement,
            at(m)
        ));
    }
    let plunges = rep
        .moves
        .iter()
        .filter(|m| m.kind == MoveKind::Plunge && m.removed > 0.0)
        .count();
    if plunges > 0 {
        s.push_str(&format!(
            "  {plunges} moves go straight down into material\n"
        ));
    }
    match rep.longest_air() {
        Some(a) => s.push_str(&format!(
            "  longest air cut {:.1} mm from X{:.3} Y{:.3} Z{:.3} ({})\n",
            a.length,
            a.start.x,
            a.start.y,
            a.start.z,
            place(rep.moves[a.report].index, lines)
        )),
        None => s.push_str("  no cut in air\n"),
    }
    let air: f64 = rep
        .moves
        .iter()
        .filter(|m| m.kind != MoveKind::Rapid)
        .map(|m| m.air)
        .sum();
    let time = rep.time();
    s.push_str(&format!(
        "  removed {:.0} mm³ in {} at the programmed feeds ({:.0} mm³/min on average); {:.0} mm of cutting moves in air\n",
        rep.removed,
        super::plan::clock(time),
        if time > 0.0 { rep.removed / time * 60.0 } else { 0.0 },
        air
    ));
    let bins = rep.removal_rate(10);
    if !bins.is_empty() {
        s.push_str("  removal rate over time (mm³/min):");
        for (t, r) in &bins {
            s.push_str(&format!(" {}:{:.0}", super::plan::clock(*t), r));
        }
        s.push('\n');
    }
    if rep.rapid_cuts > 0 {
        s.push_str(&format!(
            "  {} rapids go through material, the first at {}\n",
            rep.rapid_cuts,
            place(rep.first_rapid_cut.unwrap_or(0), lines)
        ));
    } else {
        s.push_str("  no rapid goes through material\n");
    }
    if let Some(p) = &o.part {
        match rep.first_gouge {
            Some(g) => s.push_str(&format!(
                "  gouges: {} cells ({:.2} mm²) cut into the part or below the floor Z{:.3}, the first at X{:.3} Y{:.3}\n",
                rep.gouges,
                rep.gouges as f64 * rep.cell * rep.cell,
                p.floor,
                g.x,
                g.y
            )),
            None => s.push_str("  no gouge\n"),
        }
        match rep.first_left {
            Some(l) => s.push_str(&format!(
                "  material left: {:.2} mm² the tool could reach stands above the floor ({:.3} % of the pockets), e.g. at X{:.3} Y{:.3}\n",
                rep.left_area,
                100.0 * rep.left as f64 / rep.region_cells.max(1) as f64,
                l.x,
                l.y
            )),
            None => s.push_str("  no material left that the tool could reach\n"),
        }
    }
    s
}

/// The stock from `--stock`: a box `X0,Y0,X1,Y1` or a shape file.
fn read_stock(s: &str, top: f64, job: &JobArgs) -> anyhow::Result<Stock> {
    let nums: Vec<&str> = s.split(',').map(str::trim).collect();
    if nums.len() == 4 {
        let v: Vec<f64> = nums
            .iter()
            .map(|n| n.parse::<f64>())
            .collect::<Result<_, _>>()
            .with_context(|| format!("--stock {s}: a box is four numbers X0,Y0,X1,Y1 in mm"))?;
        if v.iter().any(|x| !x.is_finite()) || v[2] <= v[0] || v[3] <= v[1] {
            bail!("--stock {s}: the box's second corner must lie above and right of the first");
        }
        return Ok(Stock::block(
            Point::new(v[0], v[1]),
            Point::new(v[2], v[3]),
            top,
        ));
    }
    let path = Path::new(s);
    if !path.exists() {
        bail!("--stock {s} is neither a box X0,Y0,X1,Y1 nor a shape file that exists");
    }
    let outline = regions_of(path, job)?;
    Ok(Stock { outline, top })
}

/// The regions of a shape file's closed outlines.
fn regions_of(path: &Path, job: &JobArgs) -> anyhow::Result<Vec<Region>> {
    let spec = JobSpec {
        operation: None,
        post: None,
        ..job.spec(path, None, None)?
    };
    let (shape, warnings) = intake::read_shape(&spec)?;
    print_warnings(&warnings);
    let regions = shape.regions();
    if regions.is_empty() {
        bail!("{} has no closed outline", path.display());
    }
    Ok(regions)
}
