//! Every post through the binary, read back by a reader we did not write where one exists,
//! and held to what the program must do, not just to its exit status:
//!
//! - `plan --post grbl|linuxcnc|generic`: the G-code is read by the `gcode` crate; an
//!   outside profile keeps the tool centre at +R from the part everywhere it cuts, an inside
//!   one at −R, every pass depth is cut round the whole loop and nothing goes deeper;
//! - `plan --post modbus`: the block text is read by the grammar of docs/modbus.md, with the
//!   same checks;
//! - `plan --op stitch --post dst|jef`: pyembroidery reads the file; every needle drop lies
//!   on the outline, no stitch is longer than asked, and the whole outline is sewn;
//! - `offset --join miter --miter-limit`: the square's corners are mitred, or bevelled once
//!   the limit is below the miter's length.

use crate::common;
use common::cli::{ok, run as machlink};
use common::pyembroidery::pyembroidery_read;

use std::path::Path;

/// The part: a 40 × 30 plate, corner at the origin.
const W: f64 = 40.0;
const H: f64 = 30.0;
const PLATE: &str = r#"{ "units": "mm", "paths": [ { "closed": true,
  "vertices": [[0,0,0],[40,0,0],[40,30,0],[0,30,0]] } ] }"#;

fn write_plate(dir: &Path) -> String {
    let p = dir.join("plate.json");
    std::fs::write(&p, PLATE).unwrap();
    p.display().to_string()
}

/// Distance from (x, y) to the plate's outline, and whether it lies inside the plate.
fn to_plate(x: f64, y: f64) -> (f64, bool) {
    let inside = x > 0.0 && x < W && y > 0.0 && y < H;
    let d = if inside {
        x.min(W - x).min(y).min(H - y)
    } else {
        let dx = (-x).max(0.0).max(x - W);
        let dy = (-y).max(0.0).max(y - H);
        dx.hypot(dy)
    };
    (d, inside)
}

/// A cutting move as read back: from, to, and for arcs the centre and direction.
#[derive(Clone, Copy, Debug)]
struct Cut {
    from: [f64; 3],
    to: [f64; 3],
    arc: Option<([f64; 2], bool)>,
}

impl Cut {
    /// Points along the move, about every 0.05 mm, ends included.
    fn samples(&self) -> Vec<[f64; 3]> {
        let [x0, y0, z0] = self.from;
        let [x1, y1, z1] = self.to;
        match self.arc {
            None => {
                let len = (x1 - x0).hypot(y1 - y0).hypot(z1 - z0);
                let n = ((len / 0.05).ceil() as usize).clamp(1, 20_000);
                (0..=n)
                    .map(|i| {
                        let t = i as f64 / n as f64;
                        [x0 + (x1 - x0) * t, y0 + (y1 - y0) * t, z0 + (z1 - z0) * t]
                    })
                    .collect()
            }
            Some(([cx, cy], ccw)) => {
                let r = (x0 - cx).hypot(y0 - cy);
                let a0 = (y0 - cy).atan2(x0 - cx);
                let a1 = (y1 - cy).atan2(x1 - cx);
                let tau = std::f64::consts::TAU;
                let mut sweep = a1 - a0;
                if ccw {
                    while sweep <= 1e-12 {
                        sweep += tau;
                    }
                } else {
                    while sweep >= -1e-12 {
                        sweep -= tau;
                    }
                }
                let n = ((r * sweep.abs() / 0.05).ceil() as usize).clamp(1, 20_000);
                (0..=n)
                    .map(|i| {
                        let t = i as f64 / n as f64;
                        let a = a0 + sweep * t;
                        [cx + r * a.cos(), cy + r * a.sin(), z0 + (z1 - z0) * t]
                    })
                    .collect()
            }
        }
    }
}

/// The cutting moves (G1, G2, G3) of a G-code program as the `gcode` crate reads it:
/// absolute millimetres (a G20 or G91 fails the test), modal motion, arcs by I, J.
fn gcode_cuts(text: &str, post: &str) -> Vec<Cut> {
    use gcode::{Code, Value};
    let program =
        gcode::parse(text).unwrap_or_else(|e| panic!("{post}: gcode reads no program: {e:?}"));
    let mut at = [0.0f64; 3];
    let mut motion: Option<u32> = None;
    let mut cuts = Vec::new();
    for block in &program.blocks {
        let mut words: Vec<(char, f64)> = Vec::new();
        for code in &block.codes {
            let (number, args) = match code {
                Code::General(g) => {
                    let n = g.number.major();
                    assert!(n != 20 && n != 91, "{post}: G{n} (inches or relative)");
                    if n <= 3 {
                        motion = Some(n);
                    }
                    (Some(n), &g.args)
                }
                Code::Miscellaneous(m) => (None, &m.args),
                Code::ToolChange(t) => (None, &t.args),
                _ => continue,
            };
            let _ = number;
            for a in args {
                if let Value::Literal(v) = a.value {
                    words.push((a.letter.to_ascii_uppercase(), f64::from(v)));
                }
            }
        }
        for w in &block.word_addresses {
            if let Value::Literal(v) = w.value {
                words.push((w.letter.to_ascii_uppercase(), f64::from(v)));
            }
        }
        let get = |c: char| words.iter().find(|w| w.0 == c).map(|w| w.1);
        if !words.iter().any(|w| matches!(w.0, 'X' | 'Y' | 'Z')) {
            continue;
        }
        let to = [
            get('X').unwrap_or(at[0]),
            get('Y').unwrap_or(at[1]),
            get('Z').unwrap_or(at[2]),
        ];
        match motion {
            Some(1) => cuts.push(Cut {
                from: at,
                to,
                arc: None,
            }),
            Some(m @ (2 | 3)) => {
                let (i, j) = (get('I').unwrap_or(0.0), get('J').unwrap_or(0.0));
                cuts.push(Cut {
                    from: at,
                    to,
                    arc: Some(([at[0] + i, at[1] + j], m == 3)),
                });
            }
            _ => {}
        }
        at = to;
    }
    cuts
}

/// The cutting moves of `plan --post modbus`, by the grammar of docs/modbus.md ("The program
/// as text"); every line must be one of its forms, and the last `end`.
fn modbus_cuts(text: &str) -> Vec<Cut> {
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.last(), Some(&"end"), "the program ends with `end`");
    let mut at = [0.0f64; 3];
    let mut cuts = Vec::new();
    for line in &lines {
        let words: Vec<&str> = line.split_whitespace().collect();
        let num = |w: &str, letter: char| -> f64 {
            let v = w
                .strip_prefix(letter)
                .unwrap_or_else(|| panic!("`{line}`: {letter} expected, found {w}"));
            // coordinates and feeds to three decimals
            let (_, frac) = v.split_once('.').unwrap_or_else(|| panic!("`{line}`: {w}"));
            assert_eq!(frac.len(), 3, "`{line}`: {w} not to three decimals");
            v.parse().unwrap_or_else(|_| panic!("`{line}`: {w}"))
        };
        match words.as_slice() {
            ["rapid", x, y, z] => at = [num(x, 'X'), num(y, 'Y'), num(z, 'Z')],
            ["linear", x, y, z, f] => {
                assert!(num(f, 'F') > 0.0, "`{line}`");
                let to = [num(x, 'X'), num(y, 'Y'), num(z, 'Z')];
                cuts.push(Cut {
                    from: at,
                    to,
                    arc: None,
                });
                at = to;
            }
            ["arc", dir @ ("cw" | "ccw"), x, y, z, i, j, f] => {
                assert!(num(f, 'F') > 0.0, "`{line}`");
                let to = [num(x, 'X'), num(y, 'Y'), num(z, 'Z')];
                let c = [at[0] + num(i, 'I'), at[1] + num(j, 'J')];
                cuts.push(Cut {
                    from: at,
                    to,
                    arc: Some((c, *dir == "ccw")),
                });
                at = to;
            }
            ["dwell", ms, "ms"] => {
                ms.parse::<u32>().unwrap_or_else(|_| panic!("`{line}`"));
            }
            ["end"] => {}
            _ => panic!("`{line}` is none of docs/modbus.md's block lines"),
        }
    }
    cuts
}

/// Holds the cuts of a profile of the plate on `side` with a tool of radius `r` to the part:
/// every point cut below the stock top at r from the outline on the side asked (arcs and
/// ramps included), nothing below `depth`, and every pass depth cut all round the loop.
fn check_profile(what: &str, cuts: &[Cut], side: &str, r: f64, depth: f64, stepdown: f64) {
    assert!(!cuts.is_empty(), "{what}: nothing cut");
    let mut lowest = f64::INFINITY;
    let mut below = 0;
    for (k, c) in cuts.iter().enumerate() {
        for [x, y, z] in c.samples() {
            lowest = lowest.min(z);
            if z >= -1e-6 {
                continue;
            }
            below += 1;
            let (d, inside) = to_plate(x, y);
            assert_eq!(
                inside,
                side == "inside",
                "{what}: cut {k} at ({x}, {y}, {z}) is on the wrong side of the part"
            );
            assert!(
                (d - r).abs() <= 2e-3,
                "{what}: cut {k} at ({x}, {y}, {z}) is {d} mm from the part, not the radius {r}"
            );
        }
    }
    assert!(below > 100, "{what}: {below} points below the stock top");
    assert!(
        (lowest + depth).abs() <= 1e-3,
        "{what}: the lowest cut is at {lowest}, the depth is {depth}"
    );
    // every pass depth all round: the outline's points moved r to the cutting side (away
    // from the inside corners, where the loop turns) each lie within 0.03 mm (the cuts are
    // sampled every 0.05 mm) of a cut at that depth
    let passes = (depth / stepdown).ceil() as usize;
    let flat: Vec<Vec<[f64; 3]>> = cuts
        .iter()
        .filter(|c| (c.from[2] - c.to[2]).abs() < 1e-6 && c.to[2] < 0.0)
        .map(|c| c.samples())
        .collect();
    let sgn = if side == "outside" { 1.0 } else { -1.0 };
    for k in 1..=passes {
        let z = -depth * k as f64 / passes as f64;
        let mut due = 0;
        let sides = [
            ([0.0, 0.0], [W, 0.0], [0.0, -1.0]),
            ([W, 0.0], [W, H], [1.0, 0.0]),
            ([W, H], [0.0, H], [0.0, 1.0]),
            ([0.0, H], [0.0, 0.0], [-1.0, 0.0]),
        ];
        for (a, b, n) in sides {
            let len = (b[0] - a[0]).hypot(b[1] - a[1]);
            let steps = (len / 0.5) as usize;
            for i in 0..=steps {
                let t = i as f64 / steps as f64;
                let s = len * t;
                if side == "inside" && (s < r + 0.01 || s > len - r - 0.01) {
                    continue;
                }
                let p = [
                    a[0] + (b[0] - a[0]) * t + sgn * n[0] * r,
                    a[1] + (b[1] - a[1]) * t + sgn * n[1] * r,
                ];
                due += 1;
                let near = flat
                    .iter()
                    .flatten()
                    .any(|q| (q[2] - z).abs() < 1e-3 && (q[0] - p[0]).hypot(q[1] - p[1]) <= 0.03);
                assert!(near, "{what}: the pass at z {z} never cuts at {p:?}");
            }
        }
        assert!(due > 200, "{what}: {due} points checked");
    }
}

#[test]
fn every_gcode_post_and_the_modbus_post_cut_profiles_at_the_radius_on_their_side_at_every_depth() {
    let dir = tempfile::tempdir().unwrap();
    let plate = write_plate(dir.path());
    for side in ["outside", "inside"] {
        for post in ["grbl", "linuxcnc", "generic", "modbus"] {
            let out = dir.path().join(format!("{side}.{post}"));
            let o = machlink(&[
                "plan",
                &plate,
                "--op",
                "profile",
                "--side",
                side,
                "--tool-diameter",
                "6",
                "--depth",
                "3",
                "--stepdown",
                "1",
                "--post",
                post,
                "-o",
                out.to_str().unwrap(),
            ]);
            let what = format!("{side} profile, --post {post}");
            ok(&o, &what);
            let text = std::fs::read_to_string(&out).unwrap();
            let cuts = if post == "modbus" {
                modbus_cuts(&text)
            } else {
                gcode_cuts(&text, post)
            };
            check_profile(&what, &cuts, side, 3.0, 3.0, 1.0);
        }
    }
}

#[test]
fn stitch_plans_written_as_dst_and_jef_are_read_by_pyembroidery_on_the_outline_within_length() {
    let dir = tempfile::tempdir().unwrap();
    let plate = write_plate(dir.path());
    let len = 2.5;
    for post in ["dst", "jef"] {
        let out = dir.path().join(format!("plate.{post}"));
        let o = machlink(&[
            "plan",
            &plate,
            "--op",
            "stitch",
            "--stitch-length",
            "2.5",
            "--post",
            post,
            "-o",
            out.to_str().unwrap(),
        ]);
        ok(&o, post);
        let recs = pyembroidery_read(&out);
        // needle drops in mm, ours the right way up; runs split at jumps, trims, colours
        let mut runs: Vec<Vec<(f64, f64)>> = vec![Vec::new()];
        for &(x, y, c) in &recs {
            if c == 0 {
                runs.last_mut().unwrap().push((x / 10.0, -y / 10.0));
            } else if !runs.last().unwrap().is_empty() {
                runs.push(Vec::new());
            }
        }
        let drops: usize = runs.iter().map(|r| r.len()).sum();
        assert!(
            drops as f64 >= 2.0 * (W + H) / len,
            "{post}: {drops} needle drops for a {} mm outline",
            2.0 * (W + H)
        );
        for run in &runs {
            for &(x, y) in run {
                let (d, _) = to_plate(x, y);
                assert!(
                    d <= 0.11,
                    "{post}: a needle drop at ({x}, {y}) is {d} mm off the outline"
                );
            }
            for w in run.windows(2) {
                let l = (w[1].0 - w[0].0).hypot(w[1].1 - w[0].1);
                assert!(l <= len + 0.15, "{post}: a stitch {l} mm long, {len} asked");
            }
        }
        // the whole outline is sewn: every point of it within 0.15 mm of a stitch
        let seg_dist = |p: (f64, f64), a: (f64, f64), b: (f64, f64)| {
            let (dx, dy) = (b.0 - a.0, b.1 - a.1);
            let l2 = dx * dx + dy * dy;
            let t = if l2 > 0.0 {
                (((p.0 - a.0) * dx + (p.1 - a.1) * dy) / l2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            (p.0 - a.0 - t * dx).hypot(p.1 - a.1 - t * dy)
        };
        let corners = [(0.0, 0.0), (W, 0.0), (W, H), (0.0, H), (0.0, 0.0)];
        for c in corners.windows(2) {
            for i in 0..=100 {
                let t = i as f64 / 100.0;
                let p = (
                    c[0].0 + (c[1].0 - c[0].0) * t,
                    c[0].1 + (c[1].1 - c[0].1) * t,
                );
                let near = runs
                    .iter()
                    .flat_map(|r| r.windows(2))
                    .map(|w| seg_dist(p, w[0], w[1]))
                    .fold(f64::INFINITY, f64::min);
                assert!(
                    near <= 0.15,
                    "{post}: the outline at {p:?} is left unsewn ({near} mm)"
                );
            }
        }
    }
}

/// The areas of the closed paths `offset` wrote (its geometry JSON), each of straight sides.
fn areas(json: &str) -> Vec<f64> {
    let shape =
        offset_core::io::json::read(json.as_bytes(), "out.json").expect("offset writes JSON");
    shape
        .paths
        .iter()
        .map(|p| {
            assert!(p.closed, "{p:?}");
            assert!(
                p.vertices.iter().all(|v| v.bulge == 0.0),
                "a miter offset has no arcs: {p:?}"
            );
            p.area().abs()
        })
        .collect()
}

#[test]
fn offset_with_miter_joins_mitres_the_corners_and_bevels_them_past_the_limit() {
    let dir = tempfile::tempdir().unwrap();
    let sq = dir.path().join("square.json");
    std::fs::write(
        &sq,
        r#"{ "units": "mm", "paths": [ { "closed": true,
  "vertices": [[0,0,0],[10,0,0],[10,10,0],[0,10,0]] } ] }"#,
    )
    .unwrap();
    let sq = sq.to_str().unwrap();
    let out = dir.path().join("out.json");
    let out_s = out.to_str().unwrap();
    // a miter of a right angle is sqrt(2) times the distance: limit 2 keeps it
    let o = machlink(&[
        "offset",
        sq,
        "-d",
        "2",
        "--join",
        "miter",
        "--miter-limit",
        "2",
        "-o",
        out_s,
    ]);
    ok(&o, "offset --join miter");
    let a = areas(&std::fs::read_to_string(&out).unwrap());
    assert_eq!(a.len(), 1);
    assert!(
        (a[0] - 14.0 * 14.0).abs() < 1e-6,
        "mitred square: area {}",
        a[0]
    );
    // limit 1 is below sqrt(2): each corner is bevelled, cutting a triangle off it
    let o = machlink(&[
        "offset",
        sq,
        "-d",
        "2",
        "--join",
        "miter",
        "--miter-limit",
        "1",
        "-o",
        out_s,
    ]);
    ok(&o, "offset --join miter --miter-limit 1");
    let b = areas(&std::fs::read_to_string(&out).unwrap());
    assert_eq!(b.len(), 1);
    assert!(
        b[0] < a[0] - 1.0 && b[0] >= 10.0 * 10.0 + 4.0 * 10.0 * 2.0 + 4.0 * 2.0 - 1e-6,
        "bevelled square: area {} (mitred {})",
        b[0],
        a[0]
    );
    // inwards the corners stay sharp whatever the limit
    let o = machlink(&[
        "offset",
        sq,
        "-d",
        "-2",
        "--join",
        "miter",
        "--miter-limit",
        "1",
        "-o",
        out_s,
    ]);
    ok(&o, "offset -d -2 --join miter");
    let c = areas(&std::fs::read_to_string(&out).unwrap());
    assert!((c[0] - 36.0).abs() < 1e-6, "shrunk square: area {}", c[0]);
}
