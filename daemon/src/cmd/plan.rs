//! `machlink plan`: plan a job offline and write the program as the post's file. The
//! planning is the intake's (`machlink::core::intake::plan`), the same `submit` uses.

use super::job::{print_warnings, JobArgs};
use anyhow::Context;
use machlink::core::intake::{self, Stages, Target};
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Args)]
pub struct PlanCmdArgs {
    /// The part to plan: a shape (.json geometry JSON, docs/geometry.md; .dxf; .svg) for 2D
    /// operations, or a mesh (.stl) or a CSV point grid (.csv, x,y,z) for rough3d, finish3d
    /// and waterline. G-code (.nc, .gcode, .ngc, .tap, .gc, .cnc) is a program already:
    /// preview, simulate or submit it as it is.
    pub file: PathBuf,
    #[command(flatten)]
    pub job: JobArgs,
    /// The program format to write: grbl, linuxcnc, generic, modbus, dst, jef (see
    /// `docs/toolpaths.md`).
    #[arg(long, default_value = "grbl")]
    pub post: String,
    /// Where to write the program.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Also print the wall-clock time of each stage (start-up, reading the shape,
    /// planning, fitting arcs, the post, writing the file, the figures), in milliseconds.
    #[arg(long)]
    pub timings: bool,
}

pub fn run(a: PlanCmdArgs) -> anyhow::Result<()> {
    let entered = Instant::now();
    offset_core::heap::hold_freed_memory();
    let mut stages = Stages::default();
    if let Some(started) = super::STARTED.get() {
        stages.add("start-up", entered - *started);
    }
    let registry = machlink::core::registry::standard();
    let post = post_named(&registry, &a.post)?;
    let spec = a.job.spec(&a.file, None, Some(a.post.clone()))?;
    stages.add("spec", entered.elapsed());
    let planned = intake::plan_timed(&spec, Target::Post(post), &mut stages)?;
    print_warnings(&planned.warnings);
    let bytes = stages.time("file", || post.file(&planned.program, &label(&a.file)))?;
    stages
        .time("write", || std::fs::write(&a.output, &bytes))
        .with_context(|| format!("cannot write {}", a.output.display()))?;
    eprintln!(
        "wrote {} ({} post: {} units, {} bytes)",
        a.output.display(),
        post.name(),
        planned.program.len(),
        bytes.len()
    );
    let shown = stages.time("figures", || {
        figures(&planned.toolpath) + &operation_figures(&planned.figures)
    });
    eprint!("{shown}");
    if a.timings {
        eprintln!("{}", timings(&stages, super::STARTED.get().copied()));
    }
    Ok(())
}

/// The stages that are geometry: the import's arc fitting, the operation, the tool path's
/// arc fitting. `--timings` reports the time outside them.
pub const GEOMETRY_STAGES: [&str; 3] = ["import fit", "plan", "fit"];

/// The `--timings` line: each stage's milliseconds in the order they ran, then the total
/// since `main` began and the part of it outside the geometry (all but
/// [`GEOMETRY_STAGES`]).
pub fn timings(stages: &Stages, started: Option<Instant>) -> String {
    let ms = |d: std::time::Duration| d.as_secs_f64() * 1e3;
    let mut out = String::from("  timings (ms):");
    for (name, took) in &stages.0 {
        out.push_str(&format!(" {name} {:.3},", ms(*took)));
    }
    let total = started.map_or_else(|| stages.0.iter().map(|(_, t)| *t).sum(), |s| s.elapsed());
    let geometry: std::time::Duration = stages
        .0
        .iter()
        .filter(|(n, _)| GEOMETRY_STAGES.contains(n))
        .map(|(_, t)| *t)
        .sum();
    out.push_str(&format!(
        " total {:.3}, outside the geometry {:.3}",
        ms(total),
        ms(total.saturating_sub(geometry))
    ));
    out
}

/// Each operation of a job of several: its tool, lengths and time, and for drilling the
/// tour's rapids against the file's order; then the number of tool changes.
pub fn operation_figures(ops: &[machlink::core::intake::recipe::OperationFigures]) -> String {
    let mut out = String::new();
    if ops.is_empty() {
        return out;
    }
    for (i, o) in ops.iter().enumerate() {
        let f = &o.figures;
        out.push_str(&format!(
            "  operation {}: {} with T{} ({}): cutting {:.1} mm, rapids {:.1} mm, {}\n",
            i + 1,
            f.name,
            f.tool.number,
            f.tool_name,
            f.cutting,
            f.rapid,
            clock(f.seconds)
        ));
        if let Some(t) = &o.tour {
            out.push_str(&format!(
                "    {} holes drilled, {} bored; rapids between them {:.1} mm in the tour, {:.1} mm in the file's order\n",
                t.drilled, t.bored, t.rapid_tour, t.rapid_file_order
            ));
        }
    }
    let changes = ops.iter().filter(|o| o.figures.tool_change).count();
    out.push_str(&format!("  tool changes: {changes}\n"));
    out
}

/// What a planner shows of a plan: lengths, moves by kind, arcs to lines, and the time it
/// takes at the default kinematics (offset_core::stats::Kinematics).
pub fn figures(tp: &offset_core::Toolpath) -> String {
    let k = offset_core::stats::Kinematics::default();
    let s = tp.stats(&k);
    let mut out = String::new();
    if s.stitches + s.jumps > 0 {
        out.push_str(&format!(
            "  {} stitches over {:.1} mm, {} jumps over {:.1} mm\n",
            s.stitches, s.cutting_length, s.jumps, s.rapid_length
        ));
        return out;
    }
    let ratio = s.arcs_to_lines().map_or_else(
        || "all arcs".to_string(),
        |r| format!("{r:.2} arcs per line"),
    );
    out.push_str(&format!(
        "  cutting {:.1} mm in {} lines and {} arcs ({ratio}); rapids {:.1} mm in {} moves; {} retracts to the safe height\n",
        s.cutting_length, s.lines, s.arcs, s.rapid_length, s.rapids, offset_core::cutsim::retracts(tp)
    ));
    // what feed control found (offset_core::cutsim::feed), first in the tool path
    if let Some(offset_core::toolpath::Move::Comment { text }) = tp.moves.first() {
        if text.starts_with("feed control:") {
            out.push_str(&format!("  {text}\n"));
        }
    }
    out.push_str(&format!(
        "  estimated time {} (cutting {}, rapids {}) at rapids {} mm/min, {} mm/s², junction deviation {} mm\n",
        clock(s.time()),
        clock(s.cutting_time),
        clock(s.rapid_time + s.dwell_time),
        k.rapid_feed,
        k.acceleration,
        k.junction_deviation
    ));
    out
}

/// Seconds as `1 h 02 min`, `4 min 07 s` or `12.3 s`.
pub fn clock(secs: f64) -> String {
    let s = secs.max(0.0);
    if s >= 3600.0 {
        format!(
            "{} h {:02} min",
            (s / 3600.0) as u64,
            ((s % 3600.0) / 60.0) as u64
        )
    } else if s >= 60.0 {
        format!("{} min {:02} s", (s / 60.0) as u64, (s % 60.0) as u64)
    } else {
        format!("{s:.1} s")
    }
}

/// The post `name` of the registry, or an error naming the posts there are.
pub fn post_named<'r>(
    registry: &'r machlink_protocols::kind::Registry,
    name: &str,
) -> anyhow::Result<&'r std::sync::Arc<dyn machlink_protocols::post::AnyPost>> {
    registry.post(name).with_context(|| {
        format!(
            "there is no post `{name}` (known: {})",
            registry.post_names().join(", ")
        )
    })
}

/// The job's label in a file header (a DST's): the input file's stem.
pub fn label(path: &std::path::Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}
