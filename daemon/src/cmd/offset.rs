//! `machlink offset`: offset a shape file and write the result as geometry JSON or SVG.

use anyhow::Context;
use offset_core::geom::Shape;
use offset_core::offset::{offset_shape, Join, OffsetOptions};
use std::path::PathBuf;

/// The corner join of `--join`.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum JoinArg {
    /// An exact arc about the corner (the true offset).
    Round,
    /// The sides extended to meet, chamfered beyond the miter limit.
    Miter,
    /// A straight line across the corner.
    Chamfer,
}

#[derive(clap::Args)]
pub struct OffsetArgs {
    /// The shape file (.json geometry; other formats as the readers allow).
    pub file: PathBuf,
    /// Offset distance in mm: positive grows closed shapes and goes left of open paths,
    /// negative shrinks closed shapes and goes right of open paths.
    #[arg(long, short = 'd', allow_negative_numbers = true)]
    pub distance: f64,
    /// How convex corners are joined.
    #[arg(long, value_enum, default_value = "round")]
    pub join: JoinArg,
    /// With `--join miter`: the longest miter, as a multiple of the distance, before it is
    /// chamfered.
    #[arg(long, default_value_t = 4.0)]
    pub miter_limit: f64,
    /// The tolerance of every approximation, mm.
    #[arg(long, default_value_t = 1e-3)]
    pub tolerance: f64,
    /// Where to write: `.svg` draws the input in grey and the offset in colour, anything
    /// else gets geometry JSON.
    #[arg(short, long)]
    pub output: PathBuf,
}

pub fn run(a: OffsetArgs) -> anyhow::Result<()> {
    offset_core::heap::hold_freed_memory();
    let bytes =
        std::fs::read(&a.file).with_context(|| format!("cannot read {}", a.file.display()))?;
    if has_extension(&a.file, "stl") {
        return offset_mesh(&a, &bytes);
    }
    let shape = offset_core::io::read_shape(&bytes, &a.file.display().to_string())?;
    let opts = OffsetOptions {
        join: match a.join {
            JoinArg::Round => Join::Round,
            JoinArg::Miter => Join::Miter,
            JoinArg::Chamfer => Join::Chamfer,
        },
        miter_limit: a.miter_limit,
        tolerance: a.tolerance,
    };
    let out: Shape = offset_shape(&shape, a.distance, &opts)
        .with_context(|| format!("cannot offset {}", a.file.display()))?;
    let is_svg = a
        .output
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("svg"));
    let text = if is_svg {
        offset_core::io::svg_out::shapes_svg(&[(&shape, "#999999"), (&out, "#d62728")])
    } else {
        offset_core::io::json::write(&out)
    };
    std::fs::write(&a.output, text)
        .with_context(|| format!("cannot write {}", a.output.display()))?;
    eprintln!(
        "wrote {} ({} paths, {} vertices)",
        a.output.display(),
        out.paths.len(),
        out.paths.iter().map(|p| p.len()).sum::<usize>()
    );
    Ok(())
}

fn has_extension(p: &std::path::Path, ext: &str) -> bool {
    p.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case(ext))
}

/// `offset part.stl`: the mesh offset by multiple normals per vertex (Kim & Yang 2005), or
/// trimmed (contoured from the exact distance) where offsets of different faces interfere,
/// or one-sided for an open surface,
/// written as binary STL, with the faces in and out, the worst distance error sampled on
/// the output and the time.
fn offset_mesh(a: &OffsetArgs, bytes: &[u8]) -> anyhow::Result<()> {
    use offset_core::mesh::{self, MeshOffsetOptions, MeshOptions};
    let name = a.file.display().to_string();
    if !has_extension(&a.output, "stl") {
        anyhow::bail!(
            "the offset of a mesh is a mesh: write it to a .stl file, not {}",
            a.output.display()
        );
    }
    let input = mesh::read_stl(bytes, &name, &MeshOptions::default())?;
    let tolerance = if a.tolerance > 0.0 { a.tolerance } else { 0.01 };
    let started = std::time::Instant::now();
    let out = mesh::offset(&input, a.distance, &MeshOffsetOptions { tolerance })
        .with_context(|| format!("cannot offset {name}"))?;
    let took = started.elapsed().as_secs_f64();
    std::fs::write(&a.output, mesh::write_stl(&out.mesh))
        .with_context(|| format!("cannot write {}", a.output.display()))?;
    let how = match out.report.method {
        mesh::OffsetMethod::MultipleNormals => "multiple normals".to_string(),
        mesh::OffsetMethod::Trimmed => format!(
            "trimmed: offsets interfere, contoured on a {:.3} mm grid",
            out.report.grid_step
        ),
        mesh::OffsetMethod::OneSided => format!(
            "one-sided: the input is open (a surface, no solid), so the result is the surface at {} mm on the side {} its faces' normals, open too, contoured on a {:.3} mm grid",
            a.distance.abs(),
            if a.distance > 0.0 { "of" } else { "against" },
            out.report.grid_step
        ),
    };
    eprintln!(
        "wrote {} ({} faces in, {} faces out, {how}; worst distance error {:.4} mm, tolerance {tolerance} mm; {took:.2} s)",
        a.output.display(),
        out.report.faces_in,
        out.report.faces_out,
        out.report.worst_error,
    );
    Ok(())
}
