//! `machlink plan` and `machlink preview` as an operator runs them: shape files in, G-code
//! and drawings out, and one clear sentence with a non-zero exit on bad input.

use crate::common;

use std::path::Path;

fn machlink(args: &[&str]) -> (bool, String) {
    let out = common::cli::run(args);
    (out.status.success(), common::cli::stderr(&out))
}

const PART_SVG: &str = r#"<svg xmlns="http://www.w3.org/2000/svg" width="60mm" height="40mm" viewBox="0 0 60 40">
<path d="M0 0 H60 V40 H0 Z M30 12 a8 8 0 1 0 0.001 0 Z" fill="black" fill-rule="evenodd"/></svg>"#;

#[test]
fn a_pocket_from_svg_plans_posts_and_previews() {
    let dir = tempfile::tempdir().unwrap();
    let svg = dir.path().join("part.svg");
    std::fs::write(&svg, PART_SVG).unwrap();
    let nc = dir.path().join("part.nc");
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let (ok, err) = machlink(&[
        "plan",
        &s(&svg),
        "--op",
        "pocket",
        "--tool-diameter",
        "6",
        "--stepover",
        "40%",
        "--depth",
        "2",
        "--stepdown",
        "1",
        "--post",
        "grbl",
        "-o",
        &s(&nc),
    ]);
    assert!(ok, "{err}");
    let gcode = std::fs::read_to_string(&nc).unwrap();
    // the island is a circle: its passes come out as arcs
    assert!(
        gcode
            .lines()
            .any(|l| l.starts_with("G2") || l.starts_with("G3")),
        "{gcode}"
    );
    let png = dir.path().join("part.png");
    let (ok, err) = machlink(&["preview", &s(&nc), "-o", &s(&png)]);
    assert!(ok, "{err}");
    let bytes = std::fs::read(&png).unwrap();
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
    let over = dir.path().join("over.svg");
    let (ok, err) = machlink(&[
        "preview",
        &s(&svg),
        "--op",
        "profile",
        "--tabs",
        "2",
        "--lead-in",
        "2",
        "-o",
        &s(&over),
    ]);
    assert!(ok, "{err}");
    let drawing = std::fs::read_to_string(&over).unwrap();
    assert!(drawing.contains("stroke-dasharray"), "rapids are dashed");
    assert!(
        drawing.contains(offset_core::preview::LINEAR_COLOUR),
        "the planned cuts are drawn over the part"
    );
    // without --op the part is drawn alone: no tool path at all
    let alone = dir.path().join("alone.svg");
    let (ok, err) = machlink(&["preview", &s(&svg), "-o", &s(&alone)]);
    assert!(ok, "{err}");
    let drawing = std::fs::read_to_string(&alone).unwrap();
    assert!(
        !drawing.contains("stroke-dasharray")
            && !drawing.contains(offset_core::preview::LINEAR_COLOUR)
    );
}

/// Plans a pocket of `name` (holding `text`) with and without `--timings`: the program is
/// the same either way, the stages are `stages` in that order, they ran one after another
/// within the total, and the part outside the geometry is the total less `geometry`.
fn check_plan_timings(name: &str, text: &str, stages_wanted: &[&str], geometry: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let part = dir.path().join(name);
    std::fs::write(&part, text).unwrap();
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let plan = |out: &Path, timings: bool| {
        let mut args = vec![
            "plan".to_string(),
            s(&part),
            "--op".into(),
            "pocket".into(),
            "--tool-diameter".into(),
            "6".into(),
            "--depth".into(),
            "2".into(),
            "-o".into(),
            s(out),
        ];
        if timings {
            args.push("--timings".into());
        }
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let (ok, err) = machlink(&args);
        assert!(ok, "{err}");
        err
    };
    let (with, without) = (dir.path().join("a.nc"), dir.path().join("b.nc"));
    let err = plan(&with, true);
    let quiet = plan(&without, false);
    assert!(!quiet.contains("timings"), "{quiet}");
    // the same program either way
    assert_eq!(
        std::fs::read(&with).unwrap(),
        std::fs::read(&without).unwrap()
    );
    let line = err
        .lines()
        .find_map(|l| l.trim().strip_prefix("timings (ms):"))
        .unwrap_or_else(|| panic!("no timings line in: {err}"));
    let mut stages = Vec::new();
    let mut total = None;
    let mut outside = None;
    for part in line.split(',') {
        let words: Vec<&str> = part.split_whitespace().collect();
        let (value, name) = words.split_last().expect("a stage and its time");
        let ms: f64 = value.parse().unwrap_or_else(|_| panic!("{part} in {line}"));
        assert!(ms >= 0.0 && ms.is_finite(), "{part}");
        match name.join(" ").as_str() {
            "total" => total = Some(ms),
            "outside the geometry" => outside = Some(ms),
            n => stages.push((n.to_string(), ms)),
        }
    }
    let names: Vec<&str> = stages.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, stages_wanted, "{name}: {line}");
    let (total, outside) = (total.expect("a total"), outside.expect("the part outside"));
    // the stages ran one after another within the total (each printed to the microsecond)
    let sum: f64 = stages.iter().map(|(_, ms)| ms).sum();
    assert!(sum <= total + 0.01 * stages.len() as f64, "{line}");
    let in_geometry: f64 = stages
        .iter()
        .filter(|(n, _)| geometry.contains(&n.as_str()))
        .map(|(_, ms)| ms)
        .sum();
    assert!(
        (total - in_geometry - outside).abs() <= 0.004,
        "{name}: outside the geometry should be the total less {geometry:?}: {line}"
    );
}

#[test]
fn plan_timings_name_every_stage_and_leave_the_program_unchanged() {
    // an SVG's arcs are fitted as it is read: no stage of their own
    check_plan_timings(
        "part.svg",
        PART_SVG,
        &[
            "start-up", "spec", "read", "plan", "fit", "post", "file", "write", "figures",
        ],
        &["plan", "fit"],
    );
}

#[test]
fn plan_timings_count_the_json_imports_arc_fitting_as_geometry() {
    // a polygon of 400 points on a circle: the import fits it with arcs, a step of its own
    let pts: Vec<String> = (0..400)
        .map(|i| {
            let a = i as f64 / 400.0 * std::f64::consts::TAU;
            format!("[{},{}]", 30.0 + 25.0 * a.cos(), 30.0 + 25.0 * a.sin())
        })
        .collect();
    let json = format!(
        r#"{{"units": "mm", "paths": [{{"closed": true, "vertices": [{}]}}]}}"#,
        pts.join(",")
    );
    check_plan_timings(
        "part.json",
        &json,
        &[
            "start-up",
            "spec",
            "read",
            "import fit",
            "plan",
            "fit",
            "post",
            "file",
            "write",
            "figures",
        ],
        &["import fit", "plan", "fit"],
    );
}

#[test]
fn bad_options_and_files_are_one_clear_sentence() {
    let dir = tempfile::tempdir().unwrap();
    let svg = dir.path().join("part.svg");
    std::fs::write(&svg, PART_SVG).unwrap();
    let out = dir.path().join("x.nc");
    let (s, o) = (svg.to_str().unwrap(), out.to_str().unwrap());
    let (ok, err) = machlink(&["plan", s, "--op", "pocket", "--stepover", "lots", "-o", o]);
    assert!(!ok);
    assert!(
        err.contains("step-over \"lots\" is neither a length in mm"),
        "{err}"
    );
    let (ok, err) = machlink(&["plan", s, "--op", "pocket", "--stepover", "5", "-o", o]);
    assert!(!ok);
    assert!(err.contains("more than the tool diameter"), "{err}");
    let dxf = dir.path().join("c.dxf");
    std::fs::write(&dxf, "0\nSECTION\n2\nENTITIES\n0\nCIRCLE\n5\n1F\n8\nCUT\n10\n0\n20\n0\n40\n10\n0\nENDSEC\n0\nEOF\n").unwrap();
    let d = dxf.to_str().unwrap();
    let (ok, err) = machlink(&["plan", d, "--op", "profile", "--layer", "ENGRAVE", "-o", o]);
    assert!(!ok);
    assert!(err.contains("no geometry on layer(s) ENGRAVE"), "{err}");
    let (ok, err) = machlink(&["plan", d, "--op", "profile", "--layer", "cut", "-o", o]);
    assert!(ok, "{err}");
}

/// The pixels of `png` within a small distance of `colour` ("#rrggbb"): their bounding box
/// as (min x, min y, max x, max y) and how many there are.
fn pixels_of(png: &[u8], colour: &str) -> (Option<[u32; 4]>, usize) {
    let img = resvg::tiny_skia::Pixmap::decode_png(png).expect("the preview is a PNG");
    let want = |k: usize| u8::from_str_radix(&colour[1 + 2 * k..3 + 2 * k], 16).unwrap();
    let (r, g, b) = (want(0), want(1), want(2));
    let (mut bbox, mut n) = (None::<[u32; 4]>, 0);
    for y in 0..img.height() {
        for x in 0..img.width() {
            let p = img.pixel(x, y).unwrap().demultiply();
            let d = (p.red() as i32 - r as i32).abs()
                + (p.green() as i32 - g as i32).abs()
                + (p.blue() as i32 - b as i32).abs();
            if p.alpha() > 200 && d < 24 {
                n += 1;
                bbox = Some(match bbox {
                    None => [x, y, x, y],
                    Some(q) => [q[0].min(x), q[1].min(y), q[2].max(x), q[3].max(y)],
                });
            }
        }
    }
    (bbox, n)
}

/// A program from another CAM, previewed as PNG: what is drawn is that program. Its lines
/// cut a 60 × 40 rectangle and its one arc a circle of radius 10 about the rectangle's
/// middle, so the line pixels span 3:2 and the arc pixels a third of their width, centred.
#[test]
fn a_gcode_preview_draws_the_program_s_own_geometry() {
    let dir = tempfile::tempdir().unwrap();
    let nc = dir.path().join("other_cam.nc");
    std::fs::write(
        &nc,
        "(from another CAM)\nG21 G90\nG0 Z5\nG0 X0 Y0\nG1 Z-1 F300\nG1 X60 F800\nG1 Y40\nG1 X0\n\
         G1 Y0\nG0 Z5\nG0 X30 Y10\nG1 Z-1 F300\nG2 X30 Y10 I0 J10 F800\nG0 Z5\nM2\n",
    )
    .unwrap();
    let png = dir.path().join("other_cam.png");
    let (ok, err) = machlink(&[
        "preview",
        nc.to_str().unwrap(),
        "-o",
        png.to_str().unwrap(),
        "--width",
        "900",
        "--no-swept",
        "--no-legend",
        "--no-scale-bar",
    ]);
    assert!(ok, "{err}");
    let bytes = std::fs::read(&png).unwrap();
    let img = resvg::tiny_skia::Pixmap::decode_png(&bytes).unwrap();
    assert_eq!(img.width(), 900, "--width sets the drawing's width");
    let (lines, n_lines) = pixels_of(&bytes, offset_core::preview::LINEAR_COLOUR);
    let (arcs, n_arcs) = pixels_of(&bytes, offset_core::preview::ARC_COLOUR);
    let (l, a) = (
        lines.expect("the lines are drawn"),
        arcs.expect("the arc is drawn"),
    );
    assert!(
        n_lines > 500 && n_arcs > 100,
        "{n_lines} line and {n_arcs} arc pixels"
    );
    let (lw, lh) = ((l[2] - l[0]) as f64, (l[3] - l[1]) as f64);
    assert!(
        (lw / lh - 1.5).abs() < 0.05,
        "the rectangle is drawn {lw} × {lh} px"
    );
    let (aw, ah) = ((a[2] - a[0]) as f64, (a[3] - a[1]) as f64);
    assert!(
        (aw / lw - 20.0 / 60.0).abs() < 0.02,
        "the circle is {aw} px across, the rectangle {lw}"
    );
    assert!(
        (ah / aw - 1.0).abs() < 0.05,
        "the circle is drawn {aw} × {ah} px"
    );
    let centre = |b: [u32; 4]| ((b[0] + b[2]) as f64 / 2.0, (b[1] + b[3]) as f64 / 2.0);
    let ((lx, ly), (ax, ay)) = (centre(l), centre(a));
    assert!(
        (lx - ax).abs() < 3.0 && (ly - ay).abs() < 3.0,
        "the circle's centre ({ax}, {ay}) is the rectangle's ({lx}, {ly})"
    );
}

/// A gear of `teeth` teeth of amplitude 3 mm on a radius of `r` mm, as a dense SVG polygon
/// (a CAD export's polyline: 20 vertices a tooth).
fn gear_svg(r: f64, teeth: usize) -> (String, Vec<(f64, f64)>) {
    let n = teeth * 20;
    let pts: Vec<(f64, f64)> = (0..n)
        .map(|i| {
            let a = i as f64 / n as f64 * std::f64::consts::TAU;
            let rr = r + 3.0 * (teeth as f64 * a).sin();
            (r + 5.0 + rr * a.cos(), r + 5.0 + rr * a.sin())
        })
        .collect();
    let d: Vec<String> = pts.iter().map(|(x, y)| format!("{x:.6} {y:.6}")).collect();
    let side = 2.0 * r + 10.0;
    let svg = format!(
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{side}mm" height="{side}mm" viewBox="0 0 {side} {side}"><path d="M{} Z" fill="black"/></svg>"#,
        d.join(" L")
    );
    (svg, pts)
}

#[test]
fn a_toothed_pocket_keeps_the_tool_off_every_tooth_in_every_pass() {
    // pass after pass each tooth's corner folds the offset back (a swallowtail the raw
    // offset takes apart): the program must still keep the cutter clear of the wall
    let (svg, pts) = gear_svg(30.0, 15);
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("gear.svg");
    std::fs::write(&file, svg).unwrap();
    let nc = dir.path().join("gear.nc");
    let (ok, err) = machlink(&[
        "plan",
        file.to_str().unwrap(),
        "--op",
        "pocket",
        "--tool-diameter",
        "6",
        "--stepover",
        "40%",
        "--depth",
        "1",
        "--post",
        "grbl",
        "-o",
        nc.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let gcode = std::fs::read_to_string(&nc).unwrap();
    // the SVG's y axis points down: the drawing's points mirrored as the import does
    let wall = |x: f64, y: f64| -> f64 {
        let side = 70.0;
        (0..pts.len())
            .map(|i| {
                let (a, b) = (pts[i], pts[(i + 1) % pts.len()]);
                let (ax, ay, bx, by) = (a.0, side - a.1, b.0, side - b.1);
                let (dx, dy) = (bx - ax, by - ay);
                let t = (((x - ax) * dx + (y - ay) * dy) / (dx * dx + dy * dy)).clamp(0.0, 1.0);
                ((x - ax - t * dx).powi(2) + (y - ay - t * dy).powi(2)).sqrt()
            })
            .fold(f64::INFINITY, f64::min)
    };
    let word = |l: &str, c: char| -> Option<f64> {
        l.split_whitespace()
            .find(|w| w.starts_with(c))
            .and_then(|w| w[1..].parse().ok())
    };
    let (mut x, mut y, mut z) = (0.0, 0.0, 0.0);
    let (mut cuts, mut nearest) = (0usize, f64::INFINITY);
    for l in gcode.lines() {
        let moving = ["G0", "G1", "G2", "G3"].iter().any(|g| l.starts_with(g));
        if !moving {
            continue;
        }
        x = word(l, 'X').unwrap_or(x);
        y = word(l, 'Y').unwrap_or(y);
        z = word(l, 'Z').unwrap_or(z);
        if z < 0.0 && !l.starts_with("G0") {
            cuts += 1;
            nearest = nearest.min(wall(x, y));
        }
    }
    assert!(cuts > 200, "only {cuts} cutting moves:\n{gcode}");
    // every cutting move's end keeps the tool's radius from the wall (G-code numbers are
    // written to 1 µm)
    assert!(
        nearest > 3.0 - 2e-3,
        "a cut ends {nearest} mm from the wall"
    );
    // and the first pass runs along it, touching the tool's radius (the wall measured is
    // the one cut)
    assert!(
        nearest < 3.0 + 2e-3,
        "no cut comes nearer the wall than {nearest} mm"
    );
}
