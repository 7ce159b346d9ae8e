//! Every kind of preview, rendered to PNG by the binary where no font can be found (an empty
//! fontconfig, no font folders), carries its legend and scale as text: the font is the one in
//! the binary. For each kind (a 2D plan with tabs, a G-code program, a stitch file, a 3D
//! finish of a mesh, a roughing of a point grid, a 3D program in the isometric view) the same
//! command writes the SVG, whose `<text>` elements say where each label is, and the PNG,
//! in which each label's box must hold dark text pixels (ink, not a solid block); drawn with
//! `--no-legend --no-scale-bar`, the same drawing loses its band.

use crate::common::bin;
use std::path::Path;
use std::process::Command;

/// A label of the drawing: its text and its box in pixels (x0, y0, x1, y1).
#[derive(Debug)]
struct Label {
    text: String,
    px: (f64, f64, f64, f64),
}

fn number_after(s: &str, key: &str) -> f64 {
    s.split(&format!("{key}=\""))
        .nth(1)
        .and_then(|r| r.split('"').next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no {key} in {s:.200}"))
}

/// The labels of an SVG preview, boxed in the PNG's pixels.
fn labels(svg: &str) -> Vec<Label> {
    let head = svg.split('>').next().unwrap();
    let (w_px, h_px) = (number_after(head, "width"), number_after(head, "height"));
    let vb: Vec<f64> = head
        .split("viewBox=\"")
        .nth(1)
        .unwrap()
        .split('"')
        .next()
        .unwrap()
        .split(' ')
        .map(|v| v.parse().unwrap())
        .collect();
    let (sx, sy) = (w_px / vb[2], h_px / vb[3]);
    svg.split("<text ")
        .skip(1)
        .map(|t| {
            let (attrs, rest) = t.split_once('>').unwrap();
            let text = rest.split("</text>").next().unwrap().to_string();
            let (x, y, size) = (
                number_after(attrs, "x"),
                number_after(attrs, "y"),
                number_after(attrs, "font-size"),
            );
            // a box around the glyphs: cap height above the baseline, a little below
            let width = text.chars().count() as f64 * size * 0.5;
            let px = (
                (x - vb[0]) * sx,
                (y - size * 0.75 - vb[1]) * sy,
                (x + width - vb[0]) * sx,
                (y + size * 0.1 - vb[1]) * sy,
            );
            Label { text, px }
        })
        .collect()
}

/// Dark pixels (as the text's #222) inside a box of the PNG.
fn dark_pixels(png: &resvg::tiny_skia::Pixmap, b: (f64, f64, f64, f64)) -> usize {
    let (w, h) = (png.width() as i64, png.height() as i64);
    let mut n = 0;
    for y in (b.1.floor() as i64).max(0)..(b.3.ceil() as i64).min(h) {
        for x in (b.0.floor() as i64).max(0)..(b.2.ceil() as i64).min(w) {
            let p = png.pixel(x as u32, y as u32).unwrap().demultiply();
            if p.alpha() > 200 && p.red() < 110 && p.green() < 110 && p.blue() < 110 {
                n += 1;
            }
        }
    }
    n
}

fn machlink(dir: &Path, args: &[&str]) {
    let fonts_conf = dir.join("fonts.conf");
    std::fs::write(
        &fonts_conf,
        "<?xml version=\"1.0\"?>\n<fontconfig></fontconfig>\n",
    )
    .unwrap();
    let out = Command::new(bin::machlink())
        .args(args)
        .current_dir(dir)
        // no font anywhere a font loader could look
        .env("FONTCONFIG_FILE", &fonts_conf)
        .env("FONTCONFIG_PATH", dir)
        .env("XDG_DATA_HOME", dir.join("no-data"))
        .env("XDG_DATA_DIRS", dir.join("no-data"))
        .env("HOME", dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "machlink {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

fn write_inputs(dir: &Path) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
    std::fs::copy(
        root.join("docs/examples/plate.json"),
        dir.join("plate.json"),
    )
    .unwrap();
    // a pyramid, closed, 40 × 40 × 10 mm
    let (a, b, c, d, t) = (
        [0., 0., 0.],
        [40., 0., 0.],
        [40., 40., 0.],
        [0., 40., 0.],
        [20., 20., 10.],
    );
    let mut stl = String::from("solid m\n");
    for f in [
        [a, c, b],
        [a, d, c],
        [a, b, t],
        [b, c, t],
        [c, d, t],
        [d, a, t],
    ] {
        stl += " facet normal 0 0 0\n  outer loop\n";
        for v in f {
            stl += &format!("   vertex {} {} {}\n", v[0], v[1], v[2]);
        }
        stl += "  endloop\n endfacet\n";
    }
    std::fs::write(dir.join("mould.stl"), stl + "endsolid m\n").unwrap();
    let mut csv = String::from("x,y,z\n");
    for j in 0..9 {
        for i in 0..9 {
            let (x, y) = (i as f64 * 5.0, j as f64 * 5.0);
            csv += &format!(
                "{x},{y},{:.3}\n",
                4.0 - ((x - 20.0).powi(2) + (y - 20.0).powi(2)) / 200.0
            );
        }
        csv += "\n";
    }
    std::fs::write(dir.join("probed.csv"), csv).unwrap();
    machlink(
        dir,
        &[
            "plan",
            "plate.json",
            "--op",
            "pocket",
            "--tool-diameter",
            "6",
            "--depth",
            "2",
            "-o",
            "plate.nc",
        ],
    );
    machlink(
        dir,
        &[
            "plan",
            "plate.json",
            "--op",
            "stitch",
            "--rows",
            "0,-3",
            "--post",
            "dst",
            "-o",
            "plate.dst",
        ],
    );
    machlink(
        dir,
        &[
            "plan",
            "mould.stl",
            "--op",
            "finish3d",
            "--cutter",
            "ball",
            "--tool-diameter",
            "6",
            "--stepover",
            "2",
            "-o",
            "finish.nc",
        ],
    );
}

#[test]
fn every_preview_kind_draws_its_legend_and_scale_in_png_with_no_system_font() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_inputs(d);
    let kinds: &[(&str, &[&str], &[&str])] = &[
        // (kind, the command's input and options, labels it must carry)
        (
            "2D plan with tabs",
            &[
                "plate.json",
                "--op",
                "profile",
                "--side",
                "outside",
                "--tabs",
                "4",
                "--tool-diameter",
                "3",
                "--depth",
                "2",
            ],
            &["outline", "start", "cut direction", "tab", "cut", "rapid"],
        ),
        (
            "G-code program",
            &["plate.nc"],
            &["start", "cut direction", "cut", "rapid"],
        ),
        ("stitch file", &["plate.dst"], &["start", "stitch"]),
        (
            "3D finish of a mesh",
            &[
                "mould.stl",
                "--op",
                "finish3d",
                "--tool-diameter",
                "6",
                "--stepover",
                "2",
            ],
            &["part", "start", "cut direction", "cut", "X", "Y", "Z"],
        ),
        (
            "point grid roughing",
            &[
                "probed.csv",
                "--op",
                "rough3d",
                "--tool-diameter",
                "6",
                "--stepdown",
                "1",
            ],
            &["part", "start", "cut direction", "cut", "X", "Y", "Z"],
        ),
        (
            "3D program, isometric",
            &["finish.nc"],
            &["start", "cut direction", "cut", "X", "Y", "Z"],
        ),
    ];
    let mut failures = Vec::new();
    for (k, (kind, input, must)) in kinds.iter().enumerate() {
        let (svg_out, png_out, bare_out) = (
            format!("k{k}.svg"),
            format!("k{k}.png"),
            format!("k{k}-bare.png"),
        );
        let run = |out: &str, extra: &[&str]| {
            let mut args = vec!["preview"];
            args.extend_from_slice(input);
            args.extend_from_slice(&["--width", "900", "-o", out]);
            args.extend_from_slice(extra);
            machlink(d, &args);
        };
        run(&svg_out, &[]);
        run(&png_out, &[]);
        run(&bare_out, &["--no-legend", "--no-scale-bar"]);
        let svg = std::fs::read_to_string(d.join(&svg_out)).unwrap();
        let png = resvg::tiny_skia::Pixmap::load_png(d.join(&png_out)).unwrap();
        let bare = resvg::tiny_skia::Pixmap::load_png(d.join(&bare_out)).unwrap();
        // the options leave the band out: the same width, shorter
        if (bare.width(), bare.height() >= png.height()) != (png.width(), false) {
            failures.push(format!("{kind}: --no-legend --no-scale-bar kept the band"));
        }
        let labels = labels(&svg);
        for want in *must {
            if !labels.iter().any(|l| l.text == *want) {
                failures.push(format!(
                    "{kind}: no label \"{want}\" (has {:?})",
                    labels.iter().map(|l| &l.text).collect::<Vec<_>>()
                ));
            }
        }
        assert!(
            labels.iter().any(|l| l.text.contains(" mm")),
            "{kind}: no scale bar label"
        );
        for l in &labels {
            let chars = l.text.chars().filter(|c| !c.is_whitespace()).count();
            let ink = dark_pixels(&png, l.px);
            if ink < 4 * chars {
                failures.push(format!(
                    "{kind}: label \"{}\" drew {ink} dark pixels in its box {:?}",
                    l.text, l.px
                ));
            }
            // text, not a block of something else dark: glyphs ink part of their box
            let area = (l.px.2 - l.px.0) * (l.px.3 - l.px.1);
            if ink as f64 > 0.7 * area {
                failures.push(format!(
                    "{kind}: label \"{}\" box is solid ({ink} of {area:.0})",
                    l.text
                ));
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
