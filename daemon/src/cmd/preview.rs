//! `machlink preview`: draw a shape file, a plan over its part, or a G-code program, as SVG
//! or PNG. A plan is made by the intake, as `plan` makes it.

use super::job::{print_warnings, JobArgs};
use anyhow::Context;
use machlink::core::intake::{self, Input, InputKind, JobSpec};
use offset_core::preview;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct PreviewArgs {
    /// What to draw: a shape file (.json, .dxf, .svg), a G-code program (.nc, .gcode,
    /// .ngc, .tap), an embroidery file (.dst, .jef), or a mesh (.stl) or point grid (.csv).
    /// With --op, the plan is drawn over the part.
    pub file: PathBuf,
    /// Where to write the drawing: .svg, or .png (rendered).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Width of the drawing in pixels.
    #[arg(long, default_value_t = 1000)]
    pub width: u32,
    /// Leave out the scale bar.
    #[arg(long)]
    pub no_scale_bar: bool,
    /// Leave out the legend.
    #[arg(long)]
    pub no_legend: bool,
    /// Leave out the band the tool sweeps under its cuts.
    #[arg(long)]
    pub no_swept: bool,
    /// Draw a G-code program in an isometric view (the default for programs that cut while
    /// Z changes, as 3D finishing does; meshes are always drawn so).
    #[arg(long)]
    pub iso: bool,
    /// Plan options, as for `machlink plan`; with --op the plan is drawn over the part.
    #[command(flatten)]
    pub job: JobArgs,
}

pub fn run(a: PreviewArgs) -> anyhow::Result<()> {
    let ext = |p: &PathBuf| {
        p.extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase())
            .unwrap_or_default()
    };
    let input = Input::from_path(&a.file)?;
    let opts = preview::PreviewOptions {
        width_px: a.width as f64,
        scale_bar: !a.no_scale_bar,
        legend: !a.no_legend,
        swept: !a.no_swept,
    };
    let kind = input.kind();
    let svg = if matches!(kind, InputKind::Mesh | InputKind::Points) {
        // a mesh, shaded in an isometric view, with the 3D plan over it
        let spec = a.job.spec(&a.file, None, None)?;
        let mesh = intake::read_mesh(&spec)?;
        let tp = match spec.operation {
            Some(_) => Some(intake::toolpath_3d(&spec, &mesh)?),
            None => None,
        };
        offset_core::preview3d::svg(Some(&mesh), tp.as_ref(), a.width as f64)
    } else if let Some(format) = stitch_format(&input.file_name) {
        // an embroidery file: its stitches and jumps
        let bytes = input.bytes()?;
        let records = match format {
            "dst" => machlink_protocols::sewing::dst::read_dst(&bytes, &input.file_name)?,
            _ => machlink_protocols::sewing::jef::read(&bytes, &input.file_name)?,
        };
        let tp = machlink_protocols::sewing::to_toolpath(&records);
        preview::svg_with(None, Some(&tp), &opts)
    } else if intake::is_gcode_file(&input.file_name) {
        let text = String::from_utf8(input.bytes()?)
            .with_context(|| format!("{} is not a text file", a.file.display()))?;
        let tp = machlink_protocols::gcode_read::read(&text)
            .with_context(|| format!("{} is not G-code we can draw", a.file.display()))?;
        if is_3d(&tp) || a.iso {
            offset_core::preview3d::svg(None, Some(&tp), a.width as f64)
        } else {
            preview::svg_with(None, Some(&tp), &opts)
        }
    } else {
        let spec = JobSpec {
            post: None,
            ..a.job.spec(&a.file, None, None)?
        };
        let (shape, warnings) = intake::read_shape(&spec)?;
        print_warnings(&warnings);
        match spec.operation {
            Some(_) => {
                let tp = intake::toolpath(&spec, &shape)?;
                preview::svg_with(Some(&shape), Some(&tp), &opts)
            }
            None => preview::svg_with(Some(&shape), None, &opts),
        }
    };
    match ext(&a.output).as_str() {
        "svg" => std::fs::write(&a.output, svg)
            .with_context(|| format!("cannot write {}", a.output.display()))?,
        "png" => {
            let png = render_png(&svg)?;
            std::fs::write(&a.output, png)
                .with_context(|| format!("cannot write {}", a.output.display()))?
        }
        other => anyhow::bail!(
            "cannot write a .{other} drawing to {} (use .svg or .png)",
            a.output.display()
        ),
    }
    eprintln!("wrote {}", a.output.display());
    Ok(())
}

/// The embroidery format of a file name (dst or jef), if it is one.
fn stitch_format(name: &str) -> Option<&'static str> {
    let ext = std::path::Path::new(name)
        .extension()
        .and_then(|e| e.to_str())?
        .to_ascii_lowercase();
    match ext.as_str() {
        "dst" => Some("dst"),
        "jef" => Some("jef"),
        _ => None,
    }
}

/// Whether a program cuts in 3D: over a fifth of its cutting moves change Z while they
/// move in XY (a 2D job's ramps and helical entries are far fewer).
fn is_3d(tp: &offset_core::Toolpath) -> bool {
    use offset_core::toolpath::{Move, P3};
    let (mut cutting, mut sloped) = (0usize, 0usize);
    tp.walk(P3::default(), |from, m, to| {
        if matches!(m, Move::Linear { .. } | Move::Arc { .. }) {
            cutting += 1;
            if (to.z - from.z).abs() > 1e-6 && from.xy().dist(to.xy()) > 1e-6 {
                sloped += 1;
            }
        }
    });
    sloped * 5 > cutting
}

/// Renders the drawing to PNG bytes.
fn render_png(svg: &str) -> anyhow::Result<Vec<u8>> {
    use resvg::{tiny_skia, usvg};
    let tree = usvg::Tree::from_str(svg, &usvg::Options::default())
        .context("cannot render the drawing")?;
    let size = tree.size().to_int_size();
    let mut pixmap = tiny_skia::Pixmap::new(size.width(), size.height())
        .context("the drawing is too large to render")?;
    resvg::render(&tree, tiny_skia::Transform::default(), &mut pixmap.as_mut());
    pixmap.encode_png().context("cannot encode the PNG")
}
