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
    /// Leave out the scale bar (and, in 3D views, the axes).
    #[arg(long)]
    pub no_scale_bar: bool,
    /// Leave out the legend.
    #[arg(long)]
    pub no_legend: bool,
    /// Leave out the band the tool sweeps under its cuts (plan views).
    #[arg(long)]
    pub no_swept: bool,
    /// Draw a G-code program in an isometric view (the default for programs that cut while
    /// Z changes, as 3D finishing does; meshes are always drawn so).
    #[arg(long)]
    pub iso: bool,
    /// Also write the program of the plan drawn (a shape file with --op or --recipe), as
    /// `plan --post POST -o FILE` writes it: the drawing is of that very program's moves.
    #[arg(long, value_name = "FILE")]
    pub program: Option<PathBuf>,
    /// With --program: the post the plan is made for and the program written with (as for
    /// `plan`); without it, a recipe is drawn as planned for grbl.
    #[arg(long, default_value = "grbl")]
    pub post: String,
    /// Plan options, as for `machlink plan`; with --op the plan is drawn over the part.
    #[command(flatten)]
    pub job: JobArgs,
}

pub fn run(a: PreviewArgs) -> anyhow::Result<()> {
    offset_core::heap::hold_freed_memory();
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
        offset_core::preview3d::svg_with(Some(&mesh), tp.as_ref(), &opts)
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
            offset_core::preview3d::svg_with(None, Some(&tp), &opts)
        } else {
            preview::svg_with(None, Some(&tp), &opts)
        }
    } else {
        if let Some(program) = &a.program {
            // the plan `plan --post` makes, drawn, and its program written beside the drawing
            let spec = a.job.spec(&a.file, None, Some(a.post.clone()))?;
            let registry = machlink::core::registry::standard();
            let post = super::plan::post_named(&registry, &a.post)?;
            if spec.operation.is_none() && spec.operations.is_empty() {
                anyhow::bail!(
                    "preview --program writes the program of a plan: give --op or --recipe for {}",
                    a.file.display()
                );
            }
            let planned = intake::plan(&spec, intake::Target::Post(post))?;
            print_warnings(&planned.warnings);
            let svg = if planned.figures.is_empty() {
                preview::svg_with(planned.shape.as_ref(), Some(&planned.toolpath), &opts)
            } else {
                let ops = legend(&planned.figures);
                preview::svg_of_job(planned.shape.as_ref(), Some(&planned.toolpath), &ops, &opts)
            };
            let bytes = post.file(&planned.program, &super::plan::label(&a.file))?;
            std::fs::write(program, &bytes)
                .with_context(|| format!("cannot write {}", program.display()))?;
            write_drawing(&a.output, &svg)?;
            eprintln!(
                "wrote {} and {} ({} post: {} units, {} bytes)",
                a.output.display(),
                program.display(),
                post.name(),
                planned.program.len(),
                bytes.len()
            );
            return Ok(());
        }
        let spec = JobSpec {
            post: None,
            ..a.job.spec(&a.file, None, None)?
        };
        if !spec.operations.is_empty() {
            // a job of operations: planned as `plan` plans it (tools given inline)
            let registry = machlink::core::registry::standard();
            let post = registry.post("grbl").context("the grbl post")?;
            let p =
                machlink::core::intake::recipe::plan_operations(&spec, intake::Target::Post(post))?;
            print_warnings(&p.warnings);
            // each operation in its tool's colour, named in the legend as `plan` names it
            let ops = legend(&p.figures);
            let svg = preview::svg_of_job(Some(&p.shape), Some(&p.toolpath), &ops, &opts);
            write_drawing(&a.output, &svg)?;
            eprintln!("wrote {}", a.output.display());
            return Ok(());
        }
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
    write_drawing(&a.output, &svg)?;
    eprintln!("wrote {}", a.output.display());
    Ok(())
}

/// The legend of a job of operations: each in its tool's colour, named as `plan` names it.
fn legend(
    figures: &[machlink::core::intake::recipe::OperationFigures],
) -> Vec<preview::LegendOperation> {
    figures
        .iter()
        .map(|o| {
            let f = &o.figures;
            preview::LegendOperation {
                first_move: f.first_move,
                tool: f.tool.number,
                diameter: f.tool.diameter,
                label: format!(
                    "T{} ({}): {}, {}",
                    f.tool.number,
                    f.tool_name,
                    f.name,
                    super::plan::clock(f.seconds)
                ),
            }
        })
        .collect()
}

/// Writes a drawing as SVG, or rendered to PNG, by the output's extension.
pub fn write_drawing(out: &std::path::Path, svg: &str) -> anyhow::Result<()> {
    let ext = out
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default();
    let bytes = match ext.as_str() {
        "svg" => svg.as_bytes().to_vec(),
        "png" => render_png(svg)?,
        other => anyhow::bail!(
            "cannot write a .{other} drawing to {} (use .svg or .png)",
            out.display()
        ),
    };
    std::fs::write(out, bytes).with_context(|| format!("cannot write {}", out.display()))
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
            // a helix (an arc whose Z changes) is a 2.5D entry, drawn in plan view
            let straight = matches!(m, Move::Linear { .. });
            if straight && (to.z - from.z).abs() > 1e-6 && from.xy().dist(to.xy()) > 1e-6 {
                sloped += 1;
            }
        }
    });
    sloped * 5 > cutting
}

/// The font every PNG's legend and scale are drawn in, carried in the binary so a machine
/// with no fonts installed draws them too: DejaVu Sans cut to ASCII and a few signs
/// (11 KB; Bitstream Vera licence, daemon/assets/DejaVuSans-LICENSE.txt).
const FONT: &[u8] = include_bytes!("../../assets/DejaVuSans-subset.ttf");

/// Rendering options that know only the carried font (system fonts are never asked for,
/// so the drawing is the same on every machine).
fn render_options() -> resvg::usvg::Options<'static> {
    let mut opt = resvg::usvg::Options {
        font_family: "DejaVu Sans".into(),
        ..Default::default()
    };
    let db = opt.fontdb_mut();
    db.load_font_data(FONT.to_vec());
    db.set_sans_serif_family("DejaVu Sans");
    db.set_serif_family("DejaVu Sans");
    db.set_monospace_family("DejaVu Sans");
    opt
}

/// Renders the drawing to pixels.
fn render_pixmap(svg: &str) -> anyhow::Result<resvg::tiny_skia::Pixmap> {
    use resvg::{tiny_skia, usvg};
    let tree = usvg::Tree::from_str(svg, &render_options()).context("cannot render the drawing")?;
    let size = tree.size().to_int_size();
    let mut pixmap = tiny_skia::Pixmap::new(size.width(), size.height())
        .context("the drawing is too large to render")?;
    resvg::render(&tree, tiny_skia::Transform::default(), &mut pixmap.as_mut());
    Ok(pixmap)
}

/// Renders the drawing to PNG bytes.
fn render_png(svg: &str) -> anyhow::Result<Vec<u8>> {
    render_pixmap(svg)?
        .encode_png()
        .context("cannot encode the PNG")
}

#[cfg(test)]
mod tests {
    use super::*;
    use offset_core::toolpath::{Move, P3};
    use offset_core::{Point, Toolpath};

    /// Pixels that differ between two renderings of the same size.
    fn differing(a: &resvg::tiny_skia::Pixmap, b: &resvg::tiny_skia::Pixmap) -> usize {
        assert_eq!((a.width(), a.height()), (b.width(), b.height()));
        a.pixels()
            .iter()
            .zip(b.pixels())
            .filter(|(p, q)| p != q)
            .count()
    }

    /// The drawing without its text elements.
    fn without_text(svg: &str) -> String {
        let mut out = String::new();
        let mut rest = svg;
        while let Some(at) = rest.find("<text") {
            out.push_str(&rest[..at]);
            let end = rest[at..]
                .find("</text>")
                .map_or(rest.len(), |e| at + e + 7);
            rest = &rest[end..];
        }
        out.push_str(rest);
        out
    }

    /// A pocket-like plan: a helix entry, then a square at depth.
    fn plan() -> Toolpath {
        let mut tp = Toolpath::new("pocket");
        tp.push(Move::Rapid {
            to: P3::new(10.0, 5.0, 3.0),
        });
        for k in 1..=4 {
            tp.push(Move::Arc {
                to: P3::new(10.0, 5.0, 3.0 - k as f64),
                center: Point::new(10.0, 7.0),
                ccw: true,
                feed: 300.0,
            });
        }
        for (x, y) in [(40.0, 5.0), (40.0, 30.0), (10.0, 30.0), (10.0, 5.0)] {
            tp.push(Move::Linear {
                to: P3::new(x, y, -1.0),
                feed: 800.0,
            });
        }
        tp
    }

    #[test]
    fn a_png_carries_its_legend_and_scale_in_the_carried_font_alone() {
        // the options know no system font: only the one in the binary can draw the text
        assert_eq!(render_options().fontdb.len(), 1);
        let opts = preview::PreviewOptions {
            width_px: 600.0,
            scale_bar: true,
            legend: true,
            swept: true,
        };
        let svg = preview::svg_with(None, Some(&plan()), &opts);
        assert!(
            svg.contains("<text"),
            "the drawing has a legend and a scale"
        );
        let with = render_pixmap(&svg).unwrap();
        let bare = render_pixmap(&without_text(&svg)).unwrap();
        let text_pixels = differing(&with, &bare);
        assert!(
            text_pixels > 200,
            "the legend's and scale's text drew only {text_pixels} pixels"
        );
    }

    #[test]
    fn a_helix_entry_keeps_a_25d_program_in_plan_view() {
        assert!(!is_3d(&plan()));
    }
}
