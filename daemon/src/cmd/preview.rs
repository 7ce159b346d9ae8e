//! `machlink preview`: draw a shape file, a plan over its part, or a G-code program, as SVG or PNG.

use crate::planning::{self, PlanParams};
use anyhow::Context;
use offset_core::preview;
use std::path::PathBuf;

#[derive(clap::Args)]
// `--op` belongs to preview itself (it is optional here); the plan options' own op
// argument is hidden and filled in from it.
#[command(mut_arg("op", |a| a.long("plan-op").hide(true).required(false).default_value("profile")))]
pub struct PreviewArgs {
    /// What to draw: a shape file (.json, .dxf, .svg) or a G-code program (.nc, .gcode,
    /// .ngc, .tap). With --op, the plan for the shape is drawn over it.
    pub file: PathBuf,
    /// Where to write the drawing: .svg, or .png (rendered).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Width of the drawing in pixels.
    #[arg(long, default_value_t = 1000)]
    pub width: u32,
    /// The operation whose tool path is drawn over the part (none: the part alone).
    #[arg(long = "op", id = "draw_op", value_enum)]
    pub op: Option<planning::Op>,
    /// Plan options, as for `machlink plan`; they take effect with --op.
    #[command(flatten)]
    pub plan: PlanParams,
}

pub fn run(a: PreviewArgs) -> anyhow::Result<()> {
    let ext = |p: &PathBuf| {
        p.extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase())
            .unwrap_or_default()
    };
    let svg = match ext(&a.file).as_str() {
        "nc" | "gcode" | "ngc" | "tap" | "cnc" => {
            let text = std::fs::read_to_string(&a.file)
                .with_context(|| format!("cannot read {}", a.file.display()))?;
            let tp = machlink_protocols::gcode_read::read(&text)
                .with_context(|| format!("{} is not G-code we can draw", a.file.display()))?;
            preview::svg(None, Some(&tp), a.width as f64)
        }
        _ => match a.op {
            Some(op) => {
                let params = PlanParams { op, ..a.plan };
                let shape = planning::read_shape_for(&a.file, &params)?;
                let tp = planning::plan_toolpath(&shape, &params)?;
                preview::svg(Some(&shape), Some(&tp), a.width as f64)
            }
            None => {
                let shape = planning::read_shape_for(&a.file, &a.plan)?;
                preview::svg(Some(&shape), None, a.width as f64)
            }
        },
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
