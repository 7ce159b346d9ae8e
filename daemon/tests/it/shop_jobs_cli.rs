//! Shop jobs through the binary: the sign plate of docs/examples (sign.dxf, sign.toml) —
//! 3 mm holes drilled with T1 in pecks, a pocket with an island and the plate cut out with
//! T2 (4 tabs), the 8 mm holes bored with T2 — planned into one program for every G-code
//! post and read back by the `gcode` crate: two tool changes, every drilled hole at its
//! circle's centre reaching the depth peck by peck, the bored holes to size, the pocket and
//! the profile held to what the single-operation tests hold. A recipe that leaves entities
//! untaken names each, and one naming a tool the machine lacks is refused naming both.
//! Against the simulated GRBL through the daemon: the job stops at each tool change, shows
//! the tool to load, nothing moves until `resume`, and every line of the planned program
//! reaches the controller once.

use crate::common;
use crate::proc;

use common::cli::{at_socket as cli, ok, run as machlink, stderr, stdout as out, wait_job_record};
use common::pyembroidery::pyembroidery_read;
use machlink::core::store::JobState;
use machlink_sim::grbl::{GrblSim, GrblSimConfig, TraceEvent};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

fn example(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../docs/examples")
        .join(name)
}

/// The sign's figures, as docs/examples/sign.dxf draws them and sign.toml cuts them.
const PLATE: [f64; 4] = [0.0, 0.0, 120.0, 80.0];
const SMALL_HOLES: [[f64; 2]; 4] = [[8.0, 8.0], [112.0, 8.0], [112.0, 72.0], [8.0, 72.0]];
const BIG_HOLES: [[f64; 2]; 2] = [[25.0, 40.0], [95.0, 40.0]];
const POCKET: [f64; 4] = [45.0, 20.0, 75.0, 60.0];
const ISLAND: [f64; 4] = [55.0, 35.0, 65.0, 45.0];
const DEPTH: f64 = 6.5;
const POCKET_DEPTH: f64 = 3.0;
const R_PLANE: f64 = 1.0;
const PECK: f64 = 2.0;
const T2_RADIUS: f64 = 3.0;

/// A move as read back by the `gcode` crate.
#[derive(Clone, Copy, Debug)]
struct Mv {
    from: [f64; 3],
    to: [f64; 3],
    rapid: bool,
    arc: Option<([f64; 2], bool)>,
}

impl Mv {
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
                let (r, sweep) = self.radius_sweep();
                let a0 = (y0 - cy).atan2(x0 - cx);
                let _ = ccw;
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
    fn radius_sweep(&self) -> (f64, f64) {
        let Some(([cx, cy], ccw)) = self.arc else {
            return (0.0, 0.0);
        };
        let [x0, y0, _] = self.from;
        let [x1, y1, _] = self.to;
        let r = (x0 - cx).hypot(y0 - cy);
        let a0 = (y0 - cy).atan2(x0 - cx);
        let a1 = (y1 - cy).atan2(x1 - cx);
        let tau = std::f64::consts::TAU;
        let mut s = a1 - a0;
        if ccw {
            while s <= 1e-12 {
                s += tau;
            }
        } else {
            while s >= -1e-12 {
                s -= tau;
            }
        }
        (r, s)
    }
}

/// A canned drilling cycle as read back: G81/G82/G83 and its words.
#[derive(Clone, Copy, Debug)]
struct Cycle {
    g: u32,
    xy: [f64; 2],
    z: f64,
    r: f64,
    q: Option<f64>,
}

/// What a program does, as the `gcode` crate reads it: moves, canned cycles and tool
/// changes (T M6), in absolute millimetres.
struct Read {
    moves: Vec<Mv>,
    cycles: Vec<Cycle>,
    m6: Vec<u32>,
}

fn read(text: &str, post: &str) -> Read {
    use gcode::{Code, Value};
    let program =
        gcode::parse(text).unwrap_or_else(|e| panic!("{post}: gcode reads no program: {e:?}"));
    let mut at = [0.0f64; 3];
    let mut motion: Option<u32> = None;
    let mut out = Read {
        moves: Vec::new(),
        cycles: Vec::new(),
        m6: Vec::new(),
    };
    for block in &program.blocks {
        let mut words: Vec<(char, f64)> = Vec::new();
        let mut cycle = None;
        let mut m6 = false;
        let mut tool = None;
        for code in &block.codes {
            let args = match code {
                Code::General(g) => {
                    let n = g.number.major();
                    assert!(n != 20 && n != 91, "{post}: G{n} (inches or relative)");
                    if n <= 3 {
                        motion = Some(n);
                    }
                    if (81..=83).contains(&n) {
                        cycle = Some(n);
                    }
                    if n == 80 {
                        motion = None;
                    }
                    &g.args
                }
                Code::Miscellaneous(m) => {
                    m6 |= m.number.major() == 6;
                    &m.args
                }
                Code::ToolChange(t) => {
                    tool = Some(t.number.major());
                    &t.args
                }
                _ => continue,
            };
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
        if m6 {
            let t = tool.or(get('T').map(|t| t as u32));
            out.m6.push(t.expect("M6 names its tool"));
        }
        if let Some(g) = cycle {
            let c = Cycle {
                g,
                xy: [get('X').unwrap(), get('Y').unwrap()],
                z: get('Z').unwrap(),
                r: get('R').unwrap(),
                q: get('Q'),
            };
            out.cycles.push(c);
            at = [c.xy[0], c.xy[1], at[2]]; // G98: back to the start height
            continue;
        }
        if !words.iter().any(|w| matches!(w.0, 'X' | 'Y' | 'Z')) {
            continue;
        }
        let to = [
            get('X').unwrap_or(at[0]),
            get('Y').unwrap_or(at[1]),
            get('Z').unwrap_or(at[2]),
        ];
        let arc = match motion {
            Some(m @ (2 | 3)) => Some((
                [
                    at[0] + get('I').unwrap_or(0.0),
                    at[1] + get('J').unwrap_or(0.0),
                ],
                m == 3,
            )),
            _ => None,
        };
        if motion.is_some() {
            out.moves.push(Mv {
                from: at,
                to,
                rapid: motion == Some(0),
                arc,
            });
        }
        at = to;
    }
    out
}

fn near(a: [f64; 2], b: [f64; 2], tol: f64) -> bool {
    (a[0] - b[0]).hypot(a[1] - b[1]) <= tol
}

/// Distance from (x, y) to the rectangle's outline, and whether it lies inside.
fn to_rect(x: f64, y: f64, [x0, y0, x1, y1]: [f64; 4]) -> (f64, bool) {
    let inside = x > x0 && x < x1 && y > y0 && y < y1;
    let d = if inside {
        (x - x0).min(x1 - x).min(y - y0).min(y1 - y)
    } else {
        let dx = (x0 - x).max(0.0).max(x - x1);
        let dy = (y0 - y).max(0.0).max(y - y1);
        dx.hypot(dy)
    };
    (d, inside)
}

/// The depths LinuxCNC's G83 feeds to: `peck` at a time down from the R plane.
fn pecks(r: f64, bottom: f64, peck: f64) -> Vec<f64> {
    let mut out = Vec::new();
    let mut z = r;
    loop {
        z -= peck;
        if z <= bottom + 1e-9 {
            out.push(bottom);
            return out;
        }
        out.push(z);
    }
}

fn plan(post: &str, dir: &Path) -> (String, String) {
    let out = dir.join(format!("sign.{post}"));
    let o = machlink(&[
        "plan".as_ref(),
        example("sign.dxf").as_os_str(),
        "--recipe".as_ref(),
        example("sign.toml").as_os_str(),
        "--post".as_ref(),
        post.as_ref(),
        "-o".as_ref(),
        out.as_os_str(),
    ]);
    ok(&o, &format!("plan --post {post}"));
    (std::fs::read_to_string(&out).unwrap(), stderr(&o))
}

#[test]
fn the_sign_recipe_is_one_program_drilled_bored_pocketed_and_cut_out_for_every_post() {
    let dir = tempfile::tempdir().unwrap();
    for post in ["grbl", "linuxcnc", "generic"] {
        let (text, said) = plan(post, dir.path());
        let r = read(&text, post);

        // two tool changes: T1 loaded first, then T2
        if post == "grbl" {
            let stops: Vec<&str> = text.lines().filter(|l| l.starts_with("M0")).collect();
            assert_eq!(
                stops,
                [
                    "M0 (load T1: 3 mm drill)",
                    "M0 (load T2: 6 mm flat end mill)"
                ],
                "{post}"
            );
            assert!(
                r.m6.is_empty() && r.cycles.is_empty(),
                "{post}: GRBL has neither"
            );
        } else {
            assert_eq!(r.m6, vec![1, 2], "{post}");
        }
        assert!(said.contains("tool changes: 2"), "{post}: {said}");
        assert!(
            said.contains("4 holes drilled, 0 bored") && said.contains("0 holes drilled, 2 bored"),
            "{said}"
        );

        // every 3 mm hole drilled once at its circle's centre, to the depth, peck by peck
        let want = pecks(R_PLANE, -DEPTH, PECK);
        for c in SMALL_HOLES {
            if post == "grbl" {
                let at: Vec<&Mv> = r
                    .moves
                    .iter()
                    .filter(|m| {
                        near([m.to[0], m.to[1]], c, 1e-6) && near([m.from[0], m.from[1]], c, 1e-6)
                    })
                    .collect();
                let feeds: Vec<f64> = at.iter().filter(|m| !m.rapid).map(|m| m.to[2]).collect();
                assert_eq!(feeds, want, "{post}: the pecks at {c:?}");
                // between two pecks the drill goes up to the R plane to clear the chips,
                // and each peck starts just above the last one's depth
                for (k, w) in at.windows(2).enumerate() {
                    if !w[1].rapid && k > 0 && w[1].from[2] < R_PLANE - 1e-9 {
                        let prev = feeds
                            .iter()
                            .rev()
                            .find(|&&z| z > w[1].to[2] + 1e-9)
                            .copied();
                        if let Some(p) = prev {
                            assert!((w[1].from[2] - (p + 0.254)).abs() < 1e-3, "{post}: {w:?}");
                        }
                    }
                }
                let retracts = at
                    .iter()
                    .filter(|m| m.rapid && (m.to[2] - R_PLANE).abs() < 1e-9)
                    .count();
                assert_eq!(retracts, want.len(), "{post}: the retracts at {c:?}");
            } else {
                let cy: Vec<&Cycle> = r.cycles.iter().filter(|y| near(y.xy, c, 1e-6)).collect();
                assert_eq!(cy.len(), 1, "{post}: the cycle at {c:?}");
                let y = cy[0];
                assert_eq!(
                    (y.g, y.z, y.r, y.q),
                    (83, -DEPTH, R_PLANE, Some(PECK)),
                    "{post}: {y:?}"
                );
            }
        }
        if post != "grbl" {
            assert_eq!(
                r.cycles.len(),
                SMALL_HOLES.len(),
                "{post}: only the 3 mm holes are cycles"
            );
        }

        // the 8 mm holes bored to size: every arc about a hole's centre at radius 4 − 3,
        // down to the depth, with a full lap at the depth
        for c in BIG_HOLES {
            let arcs: Vec<&Mv> = r
                .moves
                .iter()
                .filter(|m| m.arc.is_some_and(|(ac, _)| near(ac, c, 1e-3)))
                .collect();
            assert!(arcs.len() >= 4, "{post}: the bore at {c:?}");
            for a in &arcs {
                let (rad, _) = a.radius_sweep();
                assert!(
                    (rad + T2_RADIUS - 4.0).abs() <= 1e-3,
                    "{post}: bore radius {rad} at {c:?}"
                );
            }
            let low = arcs.iter().map(|a| a.to[2]).fold(f64::INFINITY, f64::min);
            assert!(
                (low + DEPTH).abs() < 1e-9,
                "{post}: the bore at {c:?} reaches {low}"
            );
            let lap: f64 = arcs
                .iter()
                .filter(|a| a.from[2] == -DEPTH && a.to[2] == -DEPTH)
                .map(|a| a.radius_sweep().1.abs())
                .sum();
            assert!(
                lap >= std::f64::consts::TAU - 1e-6,
                "{post}: the finishing lap at {c:?} sweeps {lap}"
            );
        }

        // the profile: every point cut outside the plate at the tool radius from it, down to
        // the depth, with tabs standing 1 mm (4 of them, at the last pass)
        // the pocket: every point cut in it at least the radius from its walls and the
        // island, to the pocket's depth, and its floor cleared
        let mut profile_low = f64::INFINITY;
        let mut pocket_low = f64::INFINITY;
        let mut floor: Vec<[f64; 2]> = Vec::new();
        let mut tab_tops = 0;
        for (k, m) in r.moves.iter().enumerate().filter(|(_, m)| !m.rapid) {
            if m.to[2] == -DEPTH + 1.0
                && m.from[2] == m.to[2]
                && !to_rect(m.to[0], m.to[1], PLATE).1
            {
                tab_tops += 1;
            }
            for [x, y, z] in m.samples() {
                if z >= -1e-6 {
                    continue;
                }
                let (dp, inside_plate) = to_rect(x, y, PLATE);
                if !inside_plate {
                    assert!(
                        (dp - T2_RADIUS).abs() <= 2e-3,
                        "{post}: move {k} at ({x}, {y}, {z}) is {dp} from the plate"
                    );
                    profile_low = profile_low.min(z);
                    continue;
                }
                let (dw, in_pocket) = to_rect(x, y, POCKET);
                if in_pocket {
                    let (di, in_island) = to_rect(x, y, ISLAND);
                    assert!(
                        !in_island,
                        "{post}: move {k} at ({x}, {y}, {z}) cuts the island"
                    );
                    assert!(dw >= T2_RADIUS - 2e-3 && di >= T2_RADIUS - 2e-3, "{post}: move {k} at ({x}, {y}, {z}) gouges: {dw} from the wall, {di} from the island");
                    pocket_low = pocket_low.min(z);
                    if (z + POCKET_DEPTH).abs() < 1e-6 {
                        floor.push([x, y]);
                    }
                }
            }
        }
        assert!(
            (profile_low + DEPTH).abs() < 1e-6,
            "{post}: the profile reaches {profile_low}"
        );
        assert!(
            (pocket_low + POCKET_DEPTH).abs() < 1e-6,
            "{post}: the pocket reaches {pocket_low}"
        );
        assert!(tab_tops >= 4, "{post}: {tab_tops} runs over tab tops");
        // the floor: every point of the pocket the tool can reach (not the outer corners
        // a round tool leaves) lies within the radius of a cut at the pocket's depth
        let mut uncut = Vec::new();
        let mut x = POCKET[0] + 0.25;
        while x < POCKET[2] {
            let mut y = POCKET[1] + 0.25;
            while y < POCKET[3] {
                let corner = (x - POCKET[0]).min(POCKET[2] - x) < T2_RADIUS
                    && (y - POCKET[1]).min(POCKET[3] - y) < T2_RADIUS;
                if !to_rect(x, y, ISLAND).1 && !corner {
                    let d = floor
                        .iter()
                        .map(|p| (p[0] - x).hypot(p[1] - y))
                        .fold(f64::INFINITY, f64::min);
                    if d > T2_RADIUS + 0.03 {
                        uncut.push((x, y, d));
                    }
                }
                y += 0.5;
            }
            x += 0.5;
        }
        assert!(
            uncut.is_empty(),
            "{post}: the pocket leaves {} points uncut, e.g. {:?}",
            uncut.len(),
            &uncut[..uncut.len().min(5)]
        );
    }
}

#[test]
fn a_recipe_that_leaves_entities_untaken_names_each_and_an_empty_operation_is_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let recipe = dir.path().join("holes.toml");
    std::fs::write(
        &recipe,
        r#"
[[operations]]
op = "drill"
tool = { number = 1, diameter = 3.0 }
take = { layers = ["HOLES"], diameter = [2.9, 3.1] }
depth = 3.0

[[operations]]
name = "engrave"
op = "profile"
side = "on"
take = { layers = ["TEXT*"] }
"#,
    )
    .unwrap();
    let out = dir.path().join("holes.nc");
    let o = machlink(&[
        "plan".as_ref(),
        example("sign.dxf").as_os_str(),
        "--recipe".as_ref(),
        recipe.as_os_str(),
        "-o".as_ref(),
        out.as_os_str(),
    ]);
    ok(&o, "plan holes.toml");
    let e = stderr(&o);
    assert!(e.contains("engrave takes nothing from sign.dxf"), "{e}");
    // the outline, the pocket's two loops and the two 8 mm circles, each by handle
    let untaken: Vec<&str> = e
        .lines()
        .filter(|l| l.contains("is taken by no operation"))
        .collect();
    assert_eq!(untaken.len(), 5, "{e}");
    for want in [
        "LWPOLYLINE (handle 101, line",
        "on layer OUTLINE",
        "CIRCLE (handle 106, line",
        "CIRCLE (handle 107, line",
        "on layer POCKET",
    ] {
        assert!(untaken.iter().any(|l| l.contains(want)), "{want}: {e}");
    }
    // a G-code tool number without a machine to look it up in is refused, saying what to do
    std::fs::write(&recipe, "[[operations]]\nop = \"drill\"\ntool = 3\n").unwrap();
    let o = machlink(&[
        "plan".as_ref(),
        example("sign.dxf").as_os_str(),
        "--recipe".as_ref(),
        recipe.as_os_str(),
        "-o".as_ref(),
        out.as_os_str(),
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("tool T3") && stderr(&o).contains("inline"),
        "{}",
        stderr(&o)
    );
}

/// The program lines the controller received, in order.
fn received(sim: &machlink_sim::grbl::GrblSimHandle) -> Vec<String> {
    sim.events()
        .into_iter()
        .filter_map(|e| match e {
            TraceEvent::Received { n: Some(_), line } => Some(line),
            _ => None,
        })
        .collect()
}

fn executed(sim: &machlink_sim::grbl::GrblSimHandle) -> usize {
    sim.events()
        .iter()
        .filter(|e| matches!(e, TraceEvent::Executed(_)))
        .count()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_simulated_grbl_stops_at_each_tool_change_until_the_operator_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let port = dir.path().join("grbl0");
    let sim = GrblSim::spawn_linked(
        GrblSimConfig {
            time_scale: 40.0,
            ..Default::default()
        },
        &port,
    )
    .unwrap();
    proc::write_config(
        dir.path(),
        &format!(
            "[[machine]]\nname = \"router\"\nlink = \"grbl\"\nport = \"{}\"\ntools = [ {{ number = 1, diameter = 3.0, name = \"3 mm drill\" }}, {{ number = 2, diameter = 6.0 }} ]\n",
            port.display()
        ),
    );
    let daemon = proc::Daemon::start(dir.path()).await;
    let sock = daemon.socket.clone();
    let (planned, _) = plan("grbl", dir.path());
    let sign = example("sign.dxf");
    let recipe = example("sign.toml");

    // a tool the machine lacks is refused, naming the tool and the machine
    let bad = dir.path().join("bad.toml");
    std::fs::write(&bad, "[[operations]]\nop = \"drill\"\ntool = 5\n").unwrap();
    let o = cli(
        &sock,
        &[
            "submit",
            sign.to_str().unwrap(),
            "--machine",
            "router",
            "--recipe",
            bad.to_str().unwrap(),
        ],
    );
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("T5") && stderr(&o).contains("machine `router` does not have"),
        "{}",
        stderr(&o)
    );

    let id = submit_recipe(&sock, &sign, "router", &recipe);
    let tools = ["load T1 (3 mm drill)", "load T2 (6 mm flat end mill)"];
    for tool in tools {
        let j = wait_job_record(&sock, id, "paused for a tool", |j| {
            j.state == JobState::Paused && j.note.as_deref().is_some_and(|n| n.contains(tool))
        });
        assert_eq!(
            j.note.as_deref(),
            Some(format!("needs operator: {tool}, then `machlink resume {id}`").as_str())
        );
        // `machines` shows the tool to load
        machines_show(&sock, &format!("needs operator: {tool}"));
        // nothing moves while the operator changes the tool
        let (moved, at) = (executed(&sim), sim.position());
        std::thread::sleep(Duration::from_millis(600));
        assert_eq!(
            (executed(&sim), sim.position()),
            (moved, at),
            "it moved during the change to {tool}"
        );
        let o = cli(&sock, &["resume", &id.to_string(), "--yes"]);
        assert!(o.status.success(), "{}", stderr(&o));
    }
    wait_job_record(&sock, id, "completed", |j| j.state == JobState::Completed);
    // every line of the program `plan` writes reached the controller once, in order
    let got = received(&sim);
    let want: Vec<String> = planned
        .lines()
        .map(|l| l.replace(' ', "").to_uppercase())
        .collect();
    let got_norm: Vec<String> = got
        .iter()
        .map(|l| l.replace(' ', "").to_uppercase())
        .collect();
    assert_eq!(
        got_norm, want,
        "the controller's lines against the planned program"
    );
}

/// The sign recipe planned (`plan -o`), previewed (`preview --program`) and submitted to
/// the simulated GRBL through the daemon is one program, byte for byte: the file `plan`
/// writes, the program `preview` wrote beside its drawing, the program the daemon stored
/// for the job (written out by the post) and the lines the controller received.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_sign_recipe_planned_previewed_and_submitted_is_one_program_byte_for_byte() {
    let dir = tempfile::tempdir().unwrap();
    let port = dir.path().join("grbl0");
    let sim = GrblSim::spawn_linked(
        GrblSimConfig {
            time_scale: 40.0,
            ..Default::default()
        },
        &port,
    )
    .unwrap();
    proc::write_config(
        dir.path(),
        &format!(
            "[[machine]]\nname = \"router\"\nlink = \"grbl\"\nport = \"{}\"\ntools = [ {{ number = 1, diameter = 3.0, name = \"3 mm drill\" }}, {{ number = 2, diameter = 6.0 }} ]\n",
            port.display()
        ),
    );
    let daemon = proc::Daemon::start(dir.path()).await;
    let sock = daemon.socket.clone();
    let (planned, _) = plan("grbl", dir.path());
    let sign = example("sign.dxf");
    let recipe = example("sign.toml");

    // preview writes the program of the plan it drew
    let drawing = dir.path().join("sign.svg");
    let previewed = dir.path().join("sign-preview.nc");
    let o = machlink(&[
        "preview".as_ref(),
        sign.as_os_str(),
        "--recipe".as_ref(),
        recipe.as_os_str(),
        "-o".as_ref(),
        drawing.as_os_str(),
        "--program".as_ref(),
        previewed.as_os_str(),
    ]);
    ok(&o, "preview --program");
    let svg = std::fs::read_to_string(&drawing).unwrap();
    assert!(svg.contains("T2 (6 mm flat end mill): cut out"), "{svg}");
    let previewed = std::fs::read(&previewed).unwrap();

    // submitted, and run to its end through both tool changes
    let id = submit_recipe(&sock, &sign, "router", &recipe);
    let until = Instant::now() + Duration::from_secs(120);
    let mut resumed = 0;
    loop {
        let j = common::cli::job_record(&sock, id);
        if j.state.is_final() {
            assert_eq!(j.state, JobState::Completed, "{j:?}");
            break;
        }
        if j.state == JobState::Paused {
            let o = cli(&sock, &["resume", &id.to_string(), "--yes"]);
            assert!(o.status.success(), "{}", stderr(&o));
            resumed += 1;
            wait_job_record(&sock, id, "resumed", |j| j.state != JobState::Paused);
        }
        assert!(Instant::now() < until, "job {id} never ended: {j:?}");
        std::thread::sleep(Duration::from_millis(50));
    }
    assert_eq!(resumed, 2, "one resume per tool change");

    // the program as the daemon stored it, written out by the grbl post
    let registry = machlink::core::registry::standard();
    let store = machlink::core::store::Store::open(&daemon.dir.join("jobs.db")).unwrap();
    let stored = store
        .program(id)
        .unwrap()
        .decode(registry.kind("grbl").unwrap().as_ref())
        .unwrap();
    let stored = registry
        .post("grbl")
        .unwrap()
        .file(&stored, "sign")
        .unwrap();
    // the lines the controller received, each ended as the file ends its lines
    let sent: String = received(&sim).iter().map(|l| format!("{l}\n")).collect();

    let planned = planned.into_bytes();
    assert!(planned.len() > 1000, "{} bytes planned", planned.len());
    for (what, got) in [
        ("preview --program", &previewed),
        ("the stored job", &stored),
        ("the controller's lines", &sent.into_bytes()),
    ] {
        let at = planned.iter().zip(got.iter()).position(|(a, b)| a != b);
        assert!(
            got == &planned,
            "{what}: {} bytes against plan's {}, first difference at byte {at:?}: {:?}",
            got.len(),
            planned.len(),
            at.map(|k| String::from_utf8_lossy(
                &got[k.saturating_sub(40)..(k + 40).min(got.len())]
            )
            .into_owned())
        );
    }
}

/// What pyembroidery reads from `path`: the command of each record (STITCH 0, JUMP 1,
/// TRIM 2, STOP 3, END 4, COLOR_CHANGE 5). Fails (never skips) without pyembroidery.
fn pyembroidery_commands(path: &Path) -> Vec<u32> {
    pyembroidery_read(path).into_iter().map(|r| r.2).collect()
}

/// The two seams of `seams_dxf`, each in its own thread (tool 1 red, tool 2 blue).
const SEAMS_RECIPE: &str =
    "[[operations]]\nop = \"stitch\"\ntool = 1\ntake = { layers = [\"SEAM-RED\"] }\n\n\
     [[operations]]\nop = \"stitch\"\ntool = 2\ntake = { layers = [\"SEAM-BLUE\"] }\n";

/// `machlink submit FILE --machine MACHINE --recipe RECIPE` against the daemon at `sock`;
/// the job's number.
fn submit_recipe(sock: &Path, file: &Path, machine: &str, recipe: &Path) -> i64 {
    let o = cli(
        sock,
        &[
            "submit",
            file.to_str().unwrap(),
            "--machine",
            machine,
            "--recipe",
            recipe.to_str().unwrap(),
        ],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    out(&o)
        .trim()
        .parse()
        .expect("submit prints the job's number")
}

/// Polls `machlink machines` (bounded, 20 s) until it shows `text`.
fn machines_show(sock: &Path, text: &str) {
    let until = Instant::now() + Duration::from_secs(20);
    loop {
        let o = cli(sock, &["machines"]);
        if out(&o).contains(text) {
            return;
        }
        assert!(
            Instant::now() < until,
            "`machines` never showed {text}: {}",
            out(&o)
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Two seams on two DXF layers, open polylines 40 mm long.
fn seams_dxf() -> String {
    let mut s = String::from("0\nSECTION\n2\nENTITIES\n");
    for (k, layer) in ["SEAM-RED", "SEAM-BLUE"].iter().enumerate() {
        let y = 10.0 + 20.0 * k as f64;
        s.push_str(&format!(
            "0\nLWPOLYLINE\n5\n{}\n8\n{layer}\n90\n2\n70\n0\n10\n0.0\n20\n{y}\n10\n40.0\n20\n{y}\n",
            200 + k
        ));
    }
    s.push_str("0\nENDSEC\n0\nEOF\n");
    s
}

#[test]
fn a_two_thread_seam_job_changes_colour_once_in_dst_and_jef() {
    let dir = tempfile::tempdir().unwrap();
    let dxf = dir.path().join("seams.dxf");
    std::fs::write(&dxf, seams_dxf()).unwrap();
    let recipe = dir.path().join("seams.toml");
    std::fs::write(&recipe, SEAMS_RECIPE).unwrap();
    for post in ["dst", "jef"] {
        let out = dir.path().join(format!("seams.{post}"));
        let o = machlink(&[
            "plan".as_ref(),
            dxf.as_os_str(),
            "--recipe".as_ref(),
            recipe.as_os_str(),
            "--post".as_ref(),
            post.as_ref(),
            "-o".as_ref(),
            out.as_os_str(),
        ]);
        ok(&o, &format!("plan seams --post {post}"));
        let cmds = pyembroidery_commands(&out);
        let changes: Vec<usize> = cmds
            .iter()
            .enumerate()
            .filter(|(_, &c)| c == 5)
            .map(|(i, _)| i)
            .collect();
        assert_eq!(changes.len(), 1, "{post}: {cmds:?}");
        // both seams are sewn, one on each side of the change
        let before = cmds[..changes[0]].iter().filter(|&&c| c == 0).count();
        let after = cmds[changes[0]..].iter().filter(|&&c| c == 0).count();
        assert!(
            before >= 10 && after >= 10,
            "{post}: {before} stitches, then {after}"
        );
    }
}

/// The two-thread seam job on a sewing machine through the daemon: the machine stops at the
/// colour change (docs/sewing-link.md rule 9a), `machines` and the job say which thread to
/// load, nothing is sewn until `resume`, and every record is sewn once.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_sewing_machine_stops_at_the_colour_change_until_the_operator_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let sim = machlink_sim::sewing::spawn_on_pty(machlink_sim::sewing::SewingSimConfig {
        time_scale: 4.0,
        spm: 3000,
        ..Default::default()
    })
    .unwrap();
    proc::write_config(
        dir.path(),
        &format!(
            "[[machine]]\nname = \"sewer\"\nlink = \"sewing\"\nport = \"{}\"\n",
            sim.path
        ),
    );
    let dxf = dir.path().join("seams.dxf");
    std::fs::write(&dxf, seams_dxf()).unwrap();
    let recipe = dir.path().join("seams.toml");
    std::fs::write(&recipe, SEAMS_RECIPE).unwrap();
    let daemon = proc::Daemon::start(dir.path()).await;
    let sock = daemon.socket.clone();
    let id = submit_recipe(&sock, &dxf, "sewer", &recipe);
    let j = wait_job_record(&sock, id, "paused at the colour change", |j| {
        j.state == JobState::Paused
    });
    assert_eq!(
        j.note.as_deref(),
        Some(
            format!("needs operator: change the thread to colour 2, then `machlink resume {id}`")
                .as_str()
        ),
        "{j:?}"
    );
    let o = cli(&sock, &["machines"]);
    assert!(
        out(&o).contains("needs operator: change the thread to colour 2"),
        "{}",
        out(&o)
    );
    // nothing is sewn while the thread is changed
    let sewn = |sim: &machlink_sim::sewing::SewingSim| sim.trace.lock().unwrap().drops.len();
    let before = sewn(&sim);
    assert!(
        before >= 10,
        "the first seam is sewn before the change: {before} stitches"
    );
    std::thread::sleep(Duration::from_millis(800));
    assert_eq!(sewn(&sim), before, "it sewed during the thread change");
    let o = cli(&sock, &["resume", &id.to_string(), "--yes"]);
    assert!(o.status.success(), "{}", stderr(&o));
    wait_job_record(&sock, id, "completed", |j| j.state == JobState::Completed);
    // every record of the pattern executed once, in order, the colour change among them
    let trace = sim.trace.lock().unwrap();
    let done: Vec<u32> = trace
        .lines
        .iter()
        .filter_map(|l| match l {
            machlink_sim::sewing::TraceLine::Record { index, .. } => Some(*index),
            _ => None,
        })
        .collect();
    assert_eq!(
        done,
        (0..done.len() as u32).collect::<Vec<_>>(),
        "records out of order or twice"
    );
    assert!(
        trace.drops.len() >= 2 * before.min(10),
        "{} stitches in all",
        trace.drops.len()
    );
    assert_eq!(
        trace
            .events
            .iter()
            .filter(|e| e.starts_with("operator stop"))
            .count(),
        1,
        "{:?}",
        trace.events
    );
}

/// Two holes of 3 mm and one of 5 mm on layer HOLES, 1 mm deep drilling for a small gantry.
fn holes_dxf() -> String {
    let mut s = String::from("0\nSECTION\n2\nENTITIES\n");
    for (k, (x, y, d)) in [(5.0, 5.0, 3.0), (15.0, 5.0, 3.0), (10.0, 12.0, 5.0)]
        .iter()
        .enumerate()
    {
        s.push_str(&format!(
            "0\nCIRCLE\n5\n{}\n8\nHOLES\n10\n{x}\n20\n{y}\n30\n0.0\n40\n{}\n",
            300 + k,
            d / 2.0
        ));
    }
    s.push_str("0\nENDSEC\n0\nEOF\n");
    s
}

/// A CANopen gantry (simulated CiA 402 drives behind an SLCAN adapter, outside the daemon)
/// runs a job of two tools: the master brings the path to rest at each tool change,
/// `machines` and the job name the tool to load, no drive moves until `resume`, and the job
/// then ends with every hole drilled.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_canopen_gantry_stops_at_each_tool_change_until_the_operator_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let bus = machlink_protocols::canopen::MemoryBus::new();
    let drives = machlink_sim::canopen::SimDrives::spawn(&bus, &[1, 2, 3], 1.0);
    let adapter = machlink_sim::canopen::spawn_adapter(&bus).unwrap();
    proc::write_config(
        dir.path(),
        &format!(
            "[[machine]]\nname = \"gantry\"\nlink = \"canopen\"\nbus = \"slcan:{}\"\n\
             period_ms = 2\nheartbeat_ms = 50\nheartbeat_timeout_ms = 1500\nreport_timeout_ms = 2000\n\
             tools = [ {{ number = 1, diameter = 3.0, name = \"3 mm drill\" }}, {{ number = 2, diameter = 5.0, name = \"5 mm drill\" }} ]\n\
             axes = [\n  {{ axis = \"x\", node = 1, counts_per_mm = 1000, max_velocity = 60, max_acceleration = 800, max_jerk = 20000 }},\n  \
             {{ axis = \"y\", node = 2, counts_per_mm = 1000, max_velocity = 50, max_acceleration = 600, max_jerk = 20000 }},\n  \
             {{ axis = \"z\", node = 3, counts_per_mm = 1000, max_velocity = 15, max_acceleration = 400, max_jerk = 20000 }},\n]\n",
            adapter.path,
        ),
    );
    let dxf = dir.path().join("holes.dxf");
    std::fs::write(&dxf, holes_dxf()).unwrap();
    let recipe = dir.path().join("holes.toml");
    std::fs::write(
        &recipe,
        "[[operations]]\nop = \"drill\"\ntool = 1\ntake = { diameter = [2.9, 3.1] }\ndepth = 1.0\nfeed = 300\n\n\
         [[operations]]\nop = \"drill\"\ntool = 2\ntake = { diameter = [4.9, 5.1] }\ndepth = 1.0\nfeed = 300\n",
    )
    .unwrap();
    let daemon = proc::Daemon::start(dir.path()).await;
    let sock = daemon.socket.clone();
    let id = submit_recipe(&sock, &dxf, "gantry", &recipe);
    // how far the drives have moved: set-points that changed a drive's actual position
    let moved = |drives: &machlink_sim::canopen::SimDrives| -> usize {
        drives
            .nodes()
            .iter()
            .map(|&n| {
                drives
                    .trace(n)
                    .windows(2)
                    .filter(|w| (w[1].actual - w[0].actual).abs() > 0.5)
                    .count()
            })
            .sum()
    };
    for tool in ["load T1 (3 mm drill)", "load T2 (5 mm drill)"] {
        let j = wait_job_record(&sock, id, "paused for a tool", |j| {
            j.state == JobState::Paused && j.note.as_deref().is_some_and(|n| n.contains(tool))
        });
        assert_eq!(
            j.note.as_deref(),
            Some(format!("needs operator: {tool}, then `machlink resume {id}`").as_str())
        );
        machines_show(&sock, &format!("needs operator: {tool}"));
        let before = moved(&drives);
        std::thread::sleep(Duration::from_millis(600));
        assert_eq!(
            moved(&drives),
            before,
            "a drive moved during the change to {tool}"
        );
        let o = cli(&sock, &["resume", &id.to_string(), "--yes"]);
        assert!(o.status.success(), "{}", stderr(&o));
    }
    let done = wait_job_record(&sock, id, "completed", |j| j.state.is_final());
    assert_eq!(done.state, JobState::Completed, "{done:?}");
    // every hole was drilled: the Z drive went down to −1 mm three times
    let z: Vec<f64> = drives.trace(3).iter().map(|r| r.actual / 1000.0).collect();
    let dips = z
        .windows(2)
        .filter(|w| w[0] > -0.999 && w[1] <= -0.999)
        .count();
    assert_eq!(dips, 3, "the Z drive reached the hole depth {dips} times");
}

/// The sign recipe for the Modbus post: a tool block (move type 7, the tool's number in the
/// feed field) at each change, T1 first and T2 after the drilling, every one where the
/// program's tool changes, and the program ends with its end block.
#[test]
fn a_modbus_program_holds_a_tool_block_at_each_tool_change() {
    let dir = tempfile::tempdir().unwrap();
    let out_file = dir.path().join("sign.blocks");
    let o = machlink(&[
        "plan".as_ref(),
        example("sign.dxf").as_os_str(),
        "--recipe".as_ref(),
        example("sign.toml").as_os_str(),
        "--post".as_ref(),
        "modbus".as_ref(),
        "-o".as_ref(),
        out_file.as_os_str(),
    ]);
    ok(&o, "plan sign --post modbus");
    let blocks = std::fs::read_to_string(&out_file).unwrap();
    let lines: Vec<&str> = blocks.lines().collect();
    let tools: Vec<(usize, &str)> = lines
        .iter()
        .enumerate()
        .filter(|(_, l)| l.starts_with("tool "))
        .map(|(i, l)| (i, *l))
        .collect();
    assert_eq!(
        tools.iter().map(|t| t.1).collect::<Vec<_>>(),
        ["tool T1", "tool T2"],
        "{blocks}"
    );
    assert_eq!(tools[0].0, 0, "T1 is loaded before any move");
    // the change to T2 comes with the tool up, after the last hole of T1 and before any cut
    // of T2: above the stock, every block before it at or above the depth of the holes
    let z = |l: &str| -> Option<f64> {
        l.split_whitespace()
            .find_map(|w| w.strip_prefix('Z'))
            .and_then(|v| v.parse().ok())
    };
    let before = z(lines[tools[1].0 - 1]).expect("a move before the change");
    assert!(before > 0.0, "the tool is at Z{before} at the change");
    assert!(
        lines
            .iter()
            .filter(|l| l.starts_with("linear") || l.starts_with("arc"))
            .count()
            > 50
    );
    assert_eq!(lines.last(), Some(&"end"));
}

/// A two-tool job to the simulated Modbus PLC through the daemon: the device holds at each
/// tool block, `machines` and the job name the tool to load (from the machine's tools
/// table), the consumed sequence does not move until `resume`, and then every block of the
/// program is executed once, in order.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_simulated_modbus_plc_stops_at_each_tool_change_until_the_operator_resumes() {
    use machlink_sim::modbus::{ModbusSim, TraceEvent as ModbusEvent};
    let dir = tempfile::tempdir().unwrap();
    let press = proc::modbus_press(
        dir.path(),
        "tools = [ { number = 1, diameter = 3.0, name = \"3 mm drill\" }, { number = 2, diameter = 5.0, name = \"5 mm drill\" } ]\n",
    )
    .await;
    let dxf = dir.path().join("holes.dxf");
    std::fs::write(&dxf, holes_dxf()).unwrap();
    let recipe = dir.path().join("holes.toml");
    std::fs::write(
        &recipe,
        "[[operations]]\nop = \"drill\"\ntool = 1\ntake = { diameter = [2.9, 3.1] }\ndepth = 1.0\nfeed = 300\n\n\
         [[operations]]\nop = \"drill\"\ntool = 2\ntake = { diameter = [4.9, 5.1] }\ndepth = 1.0\nfeed = 300\n",
    )
    .unwrap();
    let daemon = proc::Daemon::start(dir.path()).await;
    let sock = daemon.socket.clone();
    let id = submit_recipe(&sock, &dxf, "press", &recipe);
    let stops = |press: &ModbusSim| -> Vec<(u32, u32)> {
        press
            .events_from(0)
            .into_iter()
            .filter_map(|e| match e {
                ModbusEvent::ToolStop { seq, tool } => Some((seq, tool)),
                _ => None,
            })
            .collect()
    };
    for (k, (n, tool)) in [(1, "load T1 (3 mm drill)"), (2, "load T2 (5 mm drill)")]
        .into_iter()
        .enumerate()
    {
        let j = wait_job_record(&sock, id, "paused for a tool", |j| {
            j.state == JobState::Paused && j.note.as_deref().is_some_and(|n| n.contains(tool))
        });
        assert_eq!(
            j.note.as_deref(),
            Some(format!("needs operator: {tool}, then `machlink resume {id}`").as_str())
        );
        machines_show(&sock, &format!("needs operator: {tool}"));
        // the device holds at the tool block of tool n, that block not yet finished
        let s = stops(&press);
        assert_eq!(s.len(), k + 1, "{s:?}");
        let (at, t) = s[k];
        assert_eq!(t, n);
        let (state, _, consumed, _) = press.registers();
        assert_eq!((state, consumed), (2, at - 1), "held before block {at}");
        // nothing moves while the operator changes the tool
        let executed = press.trace().len();
        std::thread::sleep(Duration::from_millis(600));
        assert_eq!(
            press.registers().2,
            consumed,
            "consumed moved during the change to {tool}"
        );
        assert_eq!(
            press.trace().len(),
            executed,
            "a block ran during the change to {tool}"
        );
        let o = cli(&sock, &["resume", &id.to_string(), "--yes"]);
        assert!(o.status.success(), "{}", stderr(&o));
    }
    let done = wait_job_record(&sock, id, "completed", |j| j.state.is_final());
    assert_eq!(done.state, JobState::Completed, "{done:?}");
    // every block once, in order, the tool blocks included
    let trace = press.trace();
    let seqs: Vec<u32> = trace.iter().map(|e| e.seq).collect();
    assert_eq!(
        seqs,
        (1..=done.total_units as u32).collect::<Vec<_>>(),
        "the executed sequence"
    );
    let tools: Vec<u32> = trace
        .iter()
        .filter(|e| e.block.kind == machlink_protocols::modbus::map::BlockKind::ToolChange)
        .map(|e| e.block.feed)
        .collect();
    assert_eq!(tools, [1, 2]);
    // and the holes: the Z axis went down to −1 mm three times
    let dips = trace
        .windows(2)
        .filter(|w| w[0].block.target[2] > -999 && w[1].block.target[2] <= -999)
        .count();
    assert_eq!(dips, 3, "Z reached the hole depth {dips} times");
}

/// A machine's default recipe (`recipe = "sign.toml"` in its table): a drawing submitted
/// with no operation takes the recipe's operations, and the machine gets the very program
/// `plan --recipe` writes; a recipe that does not read is a config error naming the machine,
/// the key and its line.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_machine_default_recipe_plans_a_drawing_submitted_without_an_operation() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::copy(example("sign.toml"), dir.path().join("sign.toml")).unwrap();
    let port = dir.path().join("grbl0");
    let sim = GrblSim::spawn_linked(
        GrblSimConfig {
            time_scale: 40.0,
            ..Default::default()
        },
        &port,
    )
    .unwrap();
    let table = format!(
        "[[machine]]\nname = \"router\"\nlink = \"grbl\"\nport = \"{}\"\nrecipe = \"sign.toml\"\n\
         tools = [ {{ number = 1, diameter = 3.0, name = \"3 mm drill\" }}, {{ number = 2, diameter = 6.0 }} ]\n",
        port.display()
    );
    proc::write_config(dir.path(), &table);
    let daemon = proc::Daemon::start(dir.path()).await;
    let sock = daemon.socket.clone();
    let (planned, _) = plan("grbl", dir.path());
    let o = cli(
        &sock,
        &[
            "submit",
            example("sign.dxf").to_str().unwrap(),
            "--machine",
            "router",
        ],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let id: i64 = out(&o).trim().parse().unwrap();
    // the recipe's first tool is asked for, and the program is the recipe's, line for line
    let j = wait_job_record(&sock, id, "paused for T1", |j| {
        j.state == JobState::Paused
            && j.note
                .as_deref()
                .is_some_and(|n| n.contains("load T1 (3 mm drill)"))
    });
    assert_eq!(j.total_units as usize, planned.lines().count(), "{j:?}");
    let o = cli(&sock, &["cancel", &id.to_string()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let got: Vec<String> = received(&sim)
        .iter()
        .map(|l| l.replace(' ', "").to_uppercase())
        .collect();
    let want: Vec<String> = planned
        .lines()
        .take(got.len())
        .map(|l| l.replace(' ', "").to_uppercase())
        .collect();
    assert!(!got.is_empty() && got == want, "{got:?} against {want:?}");
    drop(daemon);

    // a recipe that does not read is refused when the config is read, naming where
    std::fs::write(
        dir.path().join("sign.toml"),
        "[[operations]]\nop = \"plunge\"\n",
    )
    .unwrap();
    let o = machlink(&[
        "check-config".as_ref(),
        dir.path().join("machlink.toml").as_os_str(),
    ]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(
        e.contains("machine `router`") && e.contains("`recipe`") && e.contains("line 9"),
        "{e}"
    );
}

/// An Inkscape drawing of a 120 × 80 mm plate: layer "Holes" (four 3 mm circles, two of them
/// in a nested group), the plate's outline as group `outline` in layer "Cut", a layer
/// "Notes" with one path, and a path in no group. Y is up in machlink: the SVG's y flips.
const LAYERED_SVG: &str = r#"<svg xmlns="http://www.w3.org/2000/svg" xmlns:inkscape="http://www.inkscape.org/namespaces/inkscape" width="120mm" height="80mm" viewBox="0 0 120 80">
  <g inkscape:groupmode="layer" inkscape:label="Holes" id="layer1">
    <circle id="h1" cx="10" cy="10" r="1.5"/>
    <circle id="h2" cx="110" cy="10" r="1.5"/>
    <g id="right-pair"><circle id="h3" cx="110" cy="70" r="1.5"/><circle id="h4" cx="10" cy="70" r="1.5"/></g>
  </g>
  <g inkscape:groupmode="layer" inkscape:label="Cut" id="layer2">
    <g id="outline"><rect id="plate" x="0" y="0" width="120" height="80"/></g>
  </g>
  <g inkscape:groupmode="layer" inkscape:label="Notes" id="layer3">
    <path id="note" d="M 40 40 L 80 40"/>
  </g>
  <path id="stray" d="M 50 50 L 60 60"/>
</svg>
"#;

/// A recipe takes an SVG's geometry by Inkscape layer label (`layer = "holes"`) and by group
/// id (`layers = ["outl*"]`, a glob): the holes are drilled at their circles' centres, the
/// outline is cut around at the tool's radius, and the paths no operation takes (a layer
/// of notes, a path in no group) are named; DXF colours on an SVG are refused.
#[test]
fn an_svg_recipe_takes_inkscape_layers_and_group_ids_and_names_the_paths_it_leaves() {
    let dir = tempfile::tempdir().unwrap();
    let svg = dir.path().join("plate.svg");
    std::fs::write(&svg, LAYERED_SVG).unwrap();
    let recipe = dir.path().join("plate.toml");
    std::fs::write(
        &recipe,
        "[[operations]]\nop = \"drill\"\ntool = { number = 1, diameter = 3.0 }\n\
         take = { layer = \"holes\", diameter = [2.9, 3.1] }\ndepth = 4.0\ncycle = \"simple\"\n\n\
         [[operations]]\nop = \"profile\"\nside = \"outside\"\ntool = { number = 2, diameter = 6.0 }\n\
         take = { layers = [\"outl*\"] }\ncut = { depth = 2.0, stepdown = 2.0, feed = 800 }\n",
    )
    .unwrap();
    let out_file = dir.path().join("plate.ngc");
    let o = machlink(&[
        "plan".as_ref(),
        svg.as_os_str(),
        "--recipe".as_ref(),
        recipe.as_os_str(),
        "--post".as_ref(),
        "linuxcnc".as_ref(),
        "-o".as_ref(),
        out_file.as_os_str(),
    ]);
    ok(&o, "plan plate.svg");
    let r = read(&std::fs::read_to_string(&out_file).unwrap(), "linuxcnc");
    // the four holes of layer Holes (the nested group's too), each drilled once at its centre
    let centres = [[10.0, 70.0], [110.0, 70.0], [110.0, 10.0], [10.0, 10.0]];
    assert_eq!(r.cycles.len(), 4, "{:?}", r.cycles);
    for c in centres {
        let n = r.cycles.iter().filter(|y| near(y.xy, c, 1e-6)).count();
        assert_eq!(n, 1, "the hole at {c:?}: {:?}", r.cycles);
    }
    assert!(r.cycles.iter().all(|y| y.g == 81 && y.z == -4.0));
    assert_eq!(r.m6, vec![1, 2]);
    // the outline, cut outside the plate at the tool's radius, and nothing else cut
    let plate = [0.0, 0.0, 120.0, 80.0];
    let mut cut = 0;
    for m in r.moves.iter().filter(|m| !m.rapid) {
        for [x, y, z] in m.samples() {
            if z < -1e-6 && !centres.iter().any(|&c| near([x, y], c, 1e-6)) {
                let (d, inside) = to_rect(x, y, plate);
                assert!(
                    !inside && (d - 3.0).abs() <= 2e-3,
                    "({x}, {y}, {z}) is {d} from the plate"
                );
                cut += 1;
            }
        }
    }
    assert!(cut > 100, "the outline was cut in {cut} samples");
    // what no operation takes is named: the note's layer and the stray path
    let e = stderr(&o);
    let untaken: Vec<&str> = e
        .lines()
        .filter(|l| l.contains("is taken by no operation"))
        .collect();
    assert_eq!(untaken.len(), 2, "{e}");
    assert!(
        untaken
            .iter()
            .any(|l| l.contains("path \"note\" in group Notes")),
        "{e}"
    );
    assert!(
        untaken
            .iter()
            .any(|l| l.contains("path \"stray\" outside every group")),
        "{e}"
    );
    // an operation whose layer the file does not have takes nothing, with a warning
    std::fs::write(
        &recipe,
        "[[operations]]\nop = \"profile\"\nside = \"on\"\nname = \"engrave\"\ntool = { number = 2, diameter = 6.0 }\n\
         take = { layer = \"Text\" }\n\n\
         [[operations]]\nop = \"profile\"\nside = \"outside\"\ntool = { number = 2, diameter = 6.0 }\n\
         take = { layers = [\"Cut\"] }\n",
    )
    .unwrap();
    let o = machlink(&[
        "plan".as_ref(),
        svg.as_os_str(),
        "--recipe".as_ref(),
        recipe.as_os_str(),
        "-o".as_ref(),
        out_file.as_os_str(),
    ]);
    ok(&o, "plan with a layer the file lacks");
    assert!(
        stderr(&o).contains("engrave takes nothing from plate.svg"),
        "{}",
        stderr(&o)
    );
    // DXF colours select nothing in an SVG: refused, saying so
    std::fs::write(
        &recipe,
        "[[operations]]\nop = \"profile\"\ntool = { number = 2, diameter = 6.0 }\ntake = { colors = [1] }\n",
    )
    .unwrap();
    let o = machlink(&[
        "plan".as_ref(),
        svg.as_os_str(),
        "--recipe".as_ref(),
        recipe.as_os_str(),
        "-o".as_ref(),
        out_file.as_os_str(),
    ]);
    assert!(!o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("plate.svg is not a DXF file: take.colors"),
        "{}",
        stderr(&o)
    );
}

/// A drill operation that takes an SVG's circles by diameter leaves the circles of other
/// sizes and the shapes that are no circle: each is named (its element and id, or its kind
/// and place without one, with the size of a circle), never silently dropped, and only the
/// circles of the tool's size are drilled.
#[test]
fn an_svg_drill_by_diameter_names_each_circle_and_shape_of_another_size_it_leaves() {
    let dir = tempfile::tempdir().unwrap();
    let svg = dir.path().join("holes.svg");
    std::fs::write(
        &svg,
        r#"<svg xmlns="http://www.w3.org/2000/svg" xmlns:inkscape="http://www.inkscape.org/namespaces/inkscape" width="100mm" height="50mm" viewBox="0 0 100 50">
  <g inkscape:groupmode="layer" inkscape:label="Holes" id="layer1">
    <circle id="h1" cx="10" cy="10" r="1.5"/>
    <circle id="big" cx="30" cy="10" r="2.5"/>
    <circle cx="50" cy="10" r="1.5"/>
    <circle cx="70" cy="10" r="2"/>
    <rect id="slot" x="80" y="5" width="10" height="3"/>
    <path d="M 10 40 A 1.5 1.5 0 1 0 13 40 A 1.5 1.5 0 1 0 10 40 Z"/>
  </g>
</svg>
"#,
    )
    .unwrap();
    let recipe = dir.path().join("holes.toml");
    std::fs::write(
        &recipe,
        "[[operations]]\nop = \"drill\"\ntool = { number = 1, diameter = 3.0 }\n\
         take = { layer = \"holes\", diameter = [2.9, 3.1] }\ndepth = 2.0\ncycle = \"simple\"\n",
    )
    .unwrap();
    let out_file = dir.path().join("holes.ngc");
    let o = machlink(&[
        "plan".as_ref(),
        svg.as_os_str(),
        "--recipe".as_ref(),
        recipe.as_os_str(),
        "--post".as_ref(),
        "linuxcnc".as_ref(),
        "-o".as_ref(),
        out_file.as_os_str(),
    ]);
    ok(&o, "plan holes.svg");
    // the three 3 mm circles (one a <path> of two arcs) are drilled, at their centres
    let r = read(&std::fs::read_to_string(&out_file).unwrap(), "linuxcnc");
    let centres = [[10.0, 40.0], [50.0, 40.0], [11.5, 10.0]];
    assert_eq!(r.cycles.len(), 3, "{:?}", r.cycles);
    for c in centres {
        assert_eq!(
            r.cycles.iter().filter(|y| near(y.xy, c, 1e-6)).count(),
            1,
            "the hole at {c:?}: {:?}",
            r.cycles
        );
    }
    // the 5 mm and 4 mm circles and the slot are each named, and nothing else is
    let e = stderr(&o);
    let untaken: Vec<&str> = e
        .lines()
        .filter(|l| l.contains("is taken by no operation"))
        .collect();
    assert_eq!(untaken.len(), 3, "{e}");
    for want in [
        "holes.svg: circle \"big\" (a circle of 5.000 mm) in group Holes / layer1 is taken by no operation of the job",
        "holes.svg: circle #4 (a circle of 4.000 mm) in group Holes / layer1 is taken by no operation of the job",
        "holes.svg: rect \"slot\" in group Holes / layer1 is taken by no operation of the job",
    ] {
        assert!(untaken.iter().any(|l| l.ends_with(want)), "{want}: {e}");
    }
}

/// The value of attribute `name` in one SVG element's text.
fn attr<'a>(element: &'a str, name: &str) -> Option<&'a str> {
    let key = format!(" {name}=\"");
    let at = element.find(&key)? + key.len();
    element[at..].split('"').next()
}

/// The points an SVG path's data passes (its M, L, H, V and A end points), in the drawing's
/// own frame.
fn path_points(d: &str) -> Vec<[f64; 2]> {
    let mut out = Vec::new();
    let mut nums: Vec<f64> = Vec::new();
    let mut cmd = ' ';
    let flush = |cmd: char, nums: &mut Vec<f64>, out: &mut Vec<[f64; 2]>| {
        match cmd {
            'M' | 'L' if nums.len() >= 2 => out.push([nums[0], nums[1]]),
            'A' if nums.len() >= 7 => out.push([nums[5], nums[6]]),
            _ => {}
        }
        nums.clear();
    };
    let mut num = String::new();
    for ch in d.chars().chain(std::iter::once(' ')) {
        if ch.is_ascii_alphabetic() {
            if !num.is_empty() {
                nums.push(num.parse().unwrap());
                num.clear();
            }
            flush(cmd, &mut nums, &mut out);
            cmd = ch;
        } else if ch == ' ' || ch == ',' {
            if !num.is_empty() {
                nums.push(num.parse().unwrap());
                num.clear();
            }
        } else if ch == '-' && !num.is_empty() {
            nums.push(num.parse().unwrap());
            num = "-".into();
        } else {
            num.push(ch);
        }
    }
    flush(cmd, &mut nums, &mut out);
    out
}

/// `preview --recipe` draws the sign in one picture: every operation's cuts in its tool's
/// colour (the drill's plunges at the 3 mm holes in T1's, the bores, the pocket and the
/// cut-out in T2's), and a legend line per operation naming its tool, the operation and the
/// time `plan` gives it, beside that colour.
#[test]
fn the_sign_preview_draws_each_operation_in_its_tool_colour_with_a_legend_of_tool_operation_and_time(
) {
    let dir = tempfile::tempdir().unwrap();
    let (_, said) = plan("grbl", dir.path());
    let svg_file = dir.path().join("sign.svg");
    let o = machlink(&[
        "preview".as_ref(),
        example("sign.dxf").as_os_str(),
        "--recipe".as_ref(),
        example("sign.toml").as_os_str(),
        "-o".as_ref(),
        svg_file.as_os_str(),
    ]);
    ok(&o, "preview --recipe");
    let svg = std::fs::read_to_string(&svg_file).unwrap();
    let lines: Vec<&str> = svg.lines().collect();
    // plan's lines: "  operation 1: drill 3 mm holes with T1 (3 mm drill): cutting …, 22.9 s"
    let ops: Vec<(String, String, String)> = said
        .lines()
        .filter_map(|l| l.trim().strip_prefix("operation "))
        .map(|l| {
            let (_, rest) = l.split_once(": ").unwrap();
            let (name, rest) = rest.split_once(" with T").unwrap();
            let (tool, rest) = rest.split_once("): ").unwrap();
            let time = rest.rsplit(", ").next().unwrap();
            (format!("T{tool})"), name.to_string(), time.to_string())
        })
        .collect();
    assert_eq!(ops.len(), 4, "{said}");
    // each operation's legend line, its colour on the line before it
    let mut colour_of = std::collections::BTreeMap::new();
    for (tool, name, time) in &ops {
        let want = format!(">{tool}: {name}, {time}</text>");
        let k = lines
            .iter()
            .position(|l| l.starts_with("<text") && l.ends_with(&want))
            .unwrap_or_else(|| panic!("no legend line {want}"));
        let colour = attr(lines[k - 1], "stroke").expect("a colour beside the legend line");
        let number = tool[1..].split(' ').next().unwrap().to_string();
        let was = colour_of.insert(number.clone(), colour.to_string());
        assert!(
            was.as_ref().is_none_or(|w| w == colour),
            "T{number} has two colours: {was:?} and {colour}"
        );
    }
    let (t1, t2) = (&colour_of["1"], &colour_of["2"]);
    assert_ne!(t1, t2, "one colour for both tools");
    // the drawing (inside the flipped group): the drill's plunges at the 3 mm holes in T1's
    // colour; every cut outside the plate (the cut-out) and about the 8 mm holes (the bores)
    // in T2's
    let start = lines
        .iter()
        .position(|l| l.starts_with("<g transform"))
        .unwrap();
    // the drawing's group ends at the last </g> (the swept band's group lies inside it)
    let end = lines.iter().rposition(|l| *l == "</g>").unwrap();
    let drawing = &lines[start..end];
    for c in SMALL_HOLES {
        let dots: Vec<&&str> = drawing
            .iter()
            .filter(|l| {
                l.starts_with("<circle")
                    && attr(l, "cx")
                        .is_some_and(|x| (x.parse::<f64>().unwrap() - c[0]).abs() < 1e-3)
                    && attr(l, "cy")
                        .is_some_and(|y| (y.parse::<f64>().unwrap() - c[1]).abs() < 1e-3)
            })
            .collect();
        assert!(
            dots.iter().any(|l| attr(l, "fill") == Some(t1)),
            "no plunge in T1's colour at {c:?}: {dots:?}"
        );
    }
    let (mut outside, mut bores) = (0, 0);
    for l in drawing.iter().filter(|l| l.starts_with("<path")) {
        let (Some(stroke), Some(d)) = (attr(l, "stroke"), attr(l, "d")) else {
            continue;
        };
        // rapids (red, dashed), the tab marks and the outline are not cuts
        if ["#d62728", "#e377c2", "#555555", "none"].contains(&stroke)
            || l.contains("stroke-dasharray")
        {
            continue;
        }
        let pts = path_points(d);
        if pts
            .iter()
            .all(|p| !to_rect(p[0], p[1], PLATE).1 && to_rect(p[0], p[1], PLATE).0 > 2.9)
        {
            assert_eq!(
                stroke, t2,
                "a cut outside the plate not in T2's colour: {l}"
            );
            outside += 1;
        }
        if d.contains('A')
            && BIG_HOLES
                .iter()
                .any(|c| pts.iter().all(|p| near(*p, *c, 1.0 + 1e-3)))
        {
            assert_eq!(stroke, t2, "a bore not in T2's colour: {l}");
            bores += 1;
        }
    }
    assert!(
        outside >= 8 && bores >= 4,
        "{outside} cut-out pieces, {bores} bore arcs"
    );
}

/// A GRBL machine that probes its tools (`probe = true`, a touch plate 1.5 mm thick at
/// (30, 20)): after each tool the operator loads and resumes, the tool goes over the plate
/// and probes down (G38.2) until it touches, the work's Z is set there (G10 L20), and only
/// then does it cut, at depths counted from the plate's top. Every line reaches the
/// controller once.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_probing_machine_measures_each_tool_on_its_touch_plate_before_it_cuts() {
    let dir = tempfile::tempdir().unwrap();
    let port = dir.path().join("grbl0");
    // the plate's top at machine Z −3: the new tool touches it there
    let contact = -3.0;
    let sim = GrblSim::spawn_linked(
        GrblSimConfig {
            time_scale: 40.0,
            touch_plate_z: Some(contact),
            ..Default::default()
        },
        &port,
    )
    .unwrap();
    let table = format!(
        "[[machine]]\nname = \"router\"\nlink = \"grbl\"\nport = \"{}\"\nprobe = true\n\
         touch_plate = {{ x = 30.0, y = 20.0, thickness = 1.5, feed = 200.0, clear = 10.0, travel = 30.0 }}\n\
         tools = [ {{ number = 1, diameter = 3.0, name = \"3 mm drill\" }}, {{ number = 2, diameter = 5.0, name = \"5 mm drill\" }} ]\n",
        port.display()
    );
    proc::write_config(dir.path(), &table);
    let dxf = dir.path().join("holes.dxf");
    std::fs::write(&dxf, holes_dxf()).unwrap();
    let recipe = dir.path().join("holes.toml");
    std::fs::write(
        &recipe,
        "[[operations]]\nop = \"drill\"\ntool = 1\ntake = { diameter = [2.9, 3.1] }\ndepth = 1.0\nfeed = 300\n\n\
         [[operations]]\nop = \"drill\"\ntool = 2\ntake = { diameter = [4.9, 5.1] }\ndepth = 1.0\nfeed = 300\n",
    )
    .unwrap();
    let daemon = proc::Daemon::start(dir.path()).await;
    let sock = daemon.socket.clone();
    let id = submit_recipe(&sock, &dxf, "router", &recipe);
    for tool in ["load T1 (3 mm drill)", "load T2 (5 mm drill)"] {
        wait_job_record(&sock, id, "paused for a tool", |j| {
            j.state == JobState::Paused && j.note.as_deref().is_some_and(|n| n.contains(tool))
        });
        machines_show(&sock, &format!("needs operator: {tool}"));
        // the controller holds at the M0 before the operator resumes it
        std::thread::sleep(Duration::from_millis(300));
        let o = cli(&sock, &["resume", &id.to_string(), "--yes"]);
        assert!(o.status.success(), "{}", stderr(&o));
    }
    let done = wait_job_record(&sock, id, "completed", |j| j.state.is_final());
    assert_eq!(done.state, JobState::Completed, "{done:?}");
    let lines = received(&sim);
    let moves: Vec<machlink_sim::grbl::Executed> = sim
        .events()
        .into_iter()
        .filter_map(|e| match e {
            TraceEvent::Executed(x) => Some(x),
            _ => None,
        })
        .collect();
    // a probe after each tool stop, at the plate, and the work's Z set there to its top
    let stops: Vec<usize> = (0..lines.len())
        .filter(|&i| lines[i].starts_with("M0"))
        .collect();
    assert_eq!(stops.len(), 2, "{lines:?}");
    for &s in &stops {
        let probe = (s..lines.len())
            .find(|&i| lines[i].starts_with("G38.2"))
            .expect("a probe after the tool stop");
        assert!(
            lines[s + 1..probe].iter().all(|l| l.starts_with("G0")),
            "only rapids between the stop and the probe: {:?}",
            &lines[s..=probe]
        );
        assert_eq!(lines[probe + 1], "G10 L20 P0 Z1.500", "{lines:?}");
        // nothing cuts between the stop and the probe
        assert!(
            !lines[s..probe]
                .iter()
                .any(|l| l.starts_with("G1") || l.starts_with("M3")),
            "{:?}",
            &lines[s..probe]
        );
    }
    let probes: Vec<&machlink_sim::grbl::Executed> = moves
        .iter()
        .filter(|m| m.line.starts_with("G38.2"))
        .collect();
    assert_eq!(probes.len(), 2, "{probes:?}");
    for p in &probes {
        assert_eq!(
            [p.to[0], p.to[1]],
            [30.0, 20.0],
            "probed off the plate: {p:?}"
        );
        assert_eq!(p.to[2], contact, "{p:?}");
    }
    // the holes go 1 mm below the stock top, the plate's top less its thickness: machine
    // Z = −3 − 1.5 − 1
    let low = moves.iter().map(|m| m.to[2]).fold(f64::INFINITY, f64::min);
    assert!(
        (low - (contact - 1.5 - 1.0)).abs() < 1e-9,
        "the deepest cut is at machine Z {low}"
    );
    // every line once, in order: the controller's count of lines
    let numbered: Vec<u64> = sim
        .events()
        .iter()
        .filter_map(|e| match e {
            TraceEvent::Received { n: Some(n), .. } => Some(*n),
            _ => None,
        })
        .collect();
    assert_eq!(numbered, (1..=numbered.len() as u64).collect::<Vec<_>>());
    assert_eq!(numbered.len() as i64, done.total_units as i64, "{done:?}");
}

/// check-config: `probe = true` needs a touch plate, its numbers are checked, and a machine
/// that runs no G-code cannot probe; each mistake names the machine and the key.
#[test]
fn a_probing_machine_needs_a_touch_plate_whose_numbers_check_config_checks() {
    let dir = tempfile::tempdir().unwrap();
    let port = dir.path().join("grbl0");
    for (link, plate, want) in [
        ("grbl", "", "probe = true needs the touch plate"),
        (
            "grbl",
            "touch_plate = { x = 30.0, y = 20.0, feed = -5.0 }\n",
            "key `touch_plate`: feed must be a positive number",
        ),
        (
            "grbl",
            "touch_plate = { x = 30.0, y = 20.0, clear = 10.0, travel = 5.0 }\n",
            "key `touch_plate`: travel (5) must reach below the plate's top",
        ),
        (
            "sewing",
            "touch_plate = { x = 30.0, y = 20.0 }\n",
            "key `probe`: a link = \"sewing\" machine runs no G-code",
        ),
    ] {
        std::fs::write(
            dir.path().join("machlink.toml"),
            format!(
                "[[machine]]\nname = \"router\"\nlink = \"{link}\"\nport = \"{}\"\nprobe = true\n{plate}",
                port.display()
            ),
        )
        .unwrap();
        let o = machlink(&[
            "check-config".as_ref(),
            dir.path().join("machlink.toml").as_os_str(),
        ]);
        assert!(!o.status.success(), "{plate}");
        assert!(
            stderr(&o).contains("machine `router`") && stderr(&o).contains(want),
            "{plate}: {}",
            stderr(&o)
        );
    }
}
