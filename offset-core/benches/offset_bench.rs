//! Offset kernel benchmark: machlink against cavalier_contours and Clipper2 on the same
//! inputs, every anchor beside every row, measured in rounds that interleave the kernels
//! (round k runs each kernel once, in an order that rotates from round to round, so a
//! burst of load from elsewhere falls on all of them alike); each time cell is the best
//! and the median of the rounds, and the load average is printed before and after each
//! case.
//!
//! Inputs (issue 25's): a gear of n vertices, r(θ) = n/10 + 3 sin(n/20 · θ) (teeth 12.6 mm
//! apart whatever n, with tips of curvature radius ≈ 1.3 mm, so a 2 mm shrink folds each
//! into a swallowtail), with and without 10 round islands (r = n/125 on a ring of radius
//! 0.6 · n/10); the 10k gear with islands offset once at 2, 20, 200 and 400 mm; 21 pocket
//! passes of it at 20, 40, … 420 mm, each from the original and each from the previous
//! pass; two dense circles offset to near collapse (30,000 points of radius 10 to 1e-3 of
//! the inradius, 100,000 points to d = -9.999).
//!
//! Every kernel runs on every row. The slow anchors are held to a time budget: a kernel
//! starts no further round of a case once its rounds there add up to the budget (so it
//! may run fewer rounds than the others; each cell says how many ran), and each Clipper2
//! round runs in a child process (this binary, `clipper-round`) that is stopped when its
//! offsets run past the row's limit (the check of its outputs is not held to it), the
//! cell then saying so.
//!
//! After the table, two blocks side by side: the gear of 1k, 10k, 100k and 1M vertices
//! with and without islands at 2 mm, and the 10k gear with islands at 2, 20, 200 and 400
//! mm, machlink and cavalier_contours on every input of a block in each round, so each
//! decade and each distance's growth is read from times taken under the same conditions
//! (the table's rows run minutes apart).
//!
//! Run: `cargo bench -p offset-core --bench offset_bench` (add `-- quick` to skip the 1M
//! rows and sizes, `-- rounds N` for N rounds instead of the defaults, `-- only TEXT` for
//! the rows whose name holds TEXT; `-- only scaling` and `-- only growth` run one block
//! alone).

use cavalier_contours::polyline::{PlineCreation, PlineSource, PlineSourceMut, Polyline as CPline};
use cavalier_contours::shape_algorithms::{Shape as CShape, ShapeOffsetOptions};
use offset_core::check::Checker;
use offset_core::geom::{Point, Polyline, Region, Vertex};
use offset_core::offset::{offset_regions_valid, OffsetOptions, ValidRegions};
use std::time::Instant;

// the planner's heap (offset_core::heap), under every kernel of the bench alike
#[global_allocator]
static HEAP: offset_core::heap::PlanningHeap = offset_core::heap::PlanningHeap;

#[derive(Debug, Default, Copy, Clone, PartialEq, Hash)]
struct Fine;
impl clipper2::PointScaler for Fine {
    const MULTIPLIER: f64 = 1e5;
}

#[path = "support/inputs.rs"]
mod inputs;
use inputs::{dense_circle, gear, gear_with_islands};

fn to_cav(p: &Polyline) -> CPline<f64> {
    let mut c = CPline::with_capacity(p.len(), p.closed);
    for v in &p.vertices {
        c.add(v.x, v.y, v.bulge);
    }
    c
}

fn from_cav(c: &CPline<f64>) -> Polyline {
    let vs = (0..c.vertex_count())
        .map(|i| {
            let v = c.at(i);
            Vertex::new(v.x, v.y, v.bulge)
        })
        .collect();
    Polyline::new(vs, c.is_closed())
}

fn flatten(p: &Polyline, tol: f64) -> Vec<(f64, f64)> {
    let mut out = Vec::new();
    for s in p.segments() {
        let k = match s {
            offset_core::Segment::Arc { radius, .. } => {
                let phi = 2.0 * (1.0 - (tol / radius).min(1.0)).acos();
                ((s.sweep().abs() / phi).ceil() as usize).max(1)
            }
            _ => 1,
        };
        for j in 0..k {
            let q = s.point_at(j as f64 / k as f64);
            out.push((q.x, q.y));
        }
    }
    out
}

/// The offsets one case asks for: each (input, distance) pair's result is what is checked.
#[derive(Clone)]
enum Plan {
    /// one offset by d
    Once(f64),
    /// one offset of the original per distance
    FromOriginal(Vec<f64>),
    /// `count` offsets by d, each of the one before
    Incremental(f64, usize),
}

impl Plan {
    fn distances(&self) -> Vec<f64> {
        match self {
            Plan::Once(d) => vec![*d],
            Plan::FromOriginal(ds) => ds.clone(),
            Plan::Incremental(d, k) => vec![*d; *k],
        }
    }
    fn chained(&self) -> bool {
        matches!(self, Plan::Incremental(..))
    }
}

/// A kernel: offsets the boundaries (outer counter-clockwise, islands clockwise) of one
/// set by `d` (negative shrinks), as boundaries again.
trait Kernel {
    type Set: Clone;
    fn load(&self, b: &[Polyline]) -> Self::Set;
    fn offset(&self, s: &Self::Set, d: f64) -> Self::Set;
    fn unload(&self, s: &Self::Set) -> Vec<Polyline>;
}

struct Machlink;

/// machlink's set: the given regions (checked when offset), or the kernel's result (a pass
/// from the previous one offsets it without the input check's crossing search).
#[derive(Clone)]
enum MlSet {
    Given(Vec<Region>),
    Made(ValidRegions),
}

impl Kernel for Machlink {
    type Set = MlSet;
    fn load(&self, b: &[Polyline]) -> MlSet {
        MlSet::Given(vec![Region::new(b[0].clone(), b[1..].to_vec())])
    }
    fn offset(&self, s: &MlSet, d: f64) -> MlSet {
        let opts = OffsetOptions::default();
        MlSet::Made(
            match s {
                MlSet::Given(r) => offset_regions_valid(r, d, &opts),
                MlSet::Made(v) => v.offset(d, &opts),
            }
            .expect("valid input"),
        )
    }
    fn unload(&self, s: &MlSet) -> Vec<Polyline> {
        let regions = match s {
            MlSet::Given(r) => r.as_slice(),
            MlSet::Made(v) => v.regions(),
        };
        regions
            .iter()
            .flat_map(|r| r.boundaries().cloned())
            .collect()
    }
}

struct Cavalier;
impl Kernel for Cavalier {
    type Set = CShape<f64>;
    fn load(&self, b: &[Polyline]) -> CShape<f64> {
        CShape::from_plines(b.iter().map(to_cav))
    }
    // positive offsets go inward of counter-clockwise loops
    fn offset(&self, s: &CShape<f64>, d: f64) -> CShape<f64> {
        s.parallel_offset(-d, &ShapeOffsetOptions::default())
    }
    fn unload(&self, s: &CShape<f64>) -> Vec<Polyline> {
        s.ccw_plines
            .iter()
            .chain(s.cw_plines.iter())
            .map(|p| from_cav(&p.polyline))
            .collect()
    }
}

/// Clipper2: polygons (arcs flattened to 1e-4), round joins at its default arc tolerance.
struct Clipper;
impl Kernel for Clipper {
    type Set = clipper2::Paths<Fine>;
    fn load(&self, b: &[Polyline]) -> clipper2::Paths<Fine> {
        let flat: Vec<Vec<(f64, f64)>> = b.iter().map(|p| flatten(p, 1e-4)).collect();
        flat.into()
    }
    fn offset(&self, s: &clipper2::Paths<Fine>, d: f64) -> clipper2::Paths<Fine> {
        clipper2::inflate(
            s.clone(),
            d,
            clipper2::JoinType::Round,
            clipper2::EndType::Polygon,
            2.0,
        )
    }
    fn unload(&self, s: &clipper2::Paths<Fine>) -> Vec<Polyline> {
        let v: Vec<Vec<(f64, f64)>> = s.clone().into();
        v.iter()
            .map(|p| {
                let pts: Vec<Point> = p.iter().map(|&(x, y)| Point::new(x, y)).collect();
                Polyline::from_points(&pts, true)
            })
            .collect()
    }
}

/// One kernel's part of a case: its times and, from its last round, the (input, distance,
/// output) of every offset.
struct Measured {
    times: Vec<f64>,
    last: Done<Vec<Polyline>>,
}

/// Each offset of a round: (input, distance, output).
type Done<S> = Vec<(S, f64, S)>;

/// Runs the plan once; returns the time (ms) of its offsets and the sets to check. Only
/// the offsets are timed: each takes its input by reference, and the (input, output)
/// pairs kept for the check are moved or copied outside the timer (a copy of a kernel's
/// set is its allocations and, for cavalier_contours, its spatial index: copying, not
/// offsetting).
fn run_once<K: Kernel>(k: &K, original: &K::Set, plan: &Plan) -> (f64, Done<K::Set>) {
    let mut spent = 0.0;
    let mut done: Done<K::Set> = Vec::new();
    for d in plan.distances() {
        let t = Instant::now();
        let out = {
            let from = match done.last() {
                Some((_, _, prev)) if plan.chained() => prev,
                _ => original,
            };
            k.offset(from, d)
        };
        spent += t.elapsed().as_secs_f64();
        let from = match done.last() {
            Some((_, _, prev)) if plan.chained() => prev.clone(),
            _ => original.clone(),
        };
        done.push((from, d, out));
    }
    (spent * 1e3, done)
}

struct Cell {
    best: f64,
    median: f64,
    rounds: usize,
    verts: usize,
    arcs: usize,
    dev: Option<f64>,
}

/// A kernel's cell of a row: measured, or stopped at the row's limit in its first round.
enum Outcome {
    Measured(Cell),
    Stopped { after_s: f64 },
}

fn count(ps: &[Polyline]) -> (usize, usize) {
    let v = ps.iter().map(|p| p.len()).sum();
    let a = ps
        .iter()
        .map(|p| {
            (0..p.segment_count())
                .filter(|&i| p.vertices[i].bulge != 0.0)
                .count()
        })
        .sum();
    (v, a)
}

fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|s| s.split_whitespace().next().map(str::to_string))
        .unwrap_or_else(|| "?".into())
}

/// How a row's outputs are checked against their inputs.
#[derive(Clone, Copy, PartialEq)]
enum Check {
    /// `offset_core::check`: every output point at the distance, and no stretch of the
    /// input left without its offset
    Full,
    /// only the distance from the input of each output segment's ends and middle (the
    /// dense circles: near their centre every distance question visits all n input
    /// segments, and the full check took minutes at 30,000 points; an empty output
    /// passes this one)
    Distance,
    /// none (the 1M rows)
    None,
}

/// The worst deviation of `out` from the offset of `input` by `d`, as `check` asks.
fn deviation(check: Check, input: &[Polyline], out: &[Polyline], d: f64) -> Option<f64> {
    let checker = Checker::new(input);
    match check {
        Check::Full => Some(checker.check(out, d, 1e-3).worst()),
        Check::Distance => {
            // each segment's ends and middle (a question near the circle's centre visits
            // every one of its n segments, all about as far)
            let mut worst: f64 = 0.0;
            for p in out {
                for s in p.segments() {
                    for t in [0.0, 0.5, 1.0] {
                        let q = s.point_at(t);
                        worst = worst.max((checker.distance(q) - d.abs()).abs());
                    }
                }
            }
            Some(worst)
        }
        Check::None => None,
    }
}

/// One row: every kernel takes part, machlink and cavalier_contours for `rounds` rounds,
/// Clipper2 for `clipper_rounds`, each kernel within `budget_s` seconds of rounds (at least
/// one round), and each Clipper2 round stopped past `clipper_limit_s`.
struct Case {
    name: String,
    boundaries: Vec<Polyline>,
    plan: Plan,
    rounds: usize,
    clipper_rounds: usize,
    check: Check,
    budget_s: f64,
    clipper_limit_s: f64,
}

fn measure<K: Kernel>(k: &K, set: &K::Set, plan: &Plan) -> (f64, Done<Vec<Polyline>>) {
    let (t, done) = run_once(k, set, plan);
    let done = done
        .iter()
        .map(|(i, d, o)| (k.unload(i), *d, k.unload(o)))
        .collect();
    (t, done)
}

/// What a Clipper2 round in the child process reports: its time and its output's
/// vertices, arcs and worst deviation.
struct ChildRound {
    ms: f64,
    verts: usize,
    arcs: usize,
    dev: Option<f64>,
}

/// Runs one Clipper2 round of case `index` in a child process (`clipper-round INDEX`),
/// stopping it when its offsets run past `limit_s` (the check of its outputs that follows
/// is not held to the limit); None when it was stopped.
fn clipper_round_in_child(index: usize, limit_s: f64) -> Option<ChildRound> {
    use std::io::BufRead;
    let exe = std::env::current_exe().expect("the bench knows its own path");
    let mut child = std::process::Command::new(exe)
        .args(["clipper-round", &index.to_string()])
        .stdout(std::process::Stdio::piped())
        .spawn()
        .expect("the bench can start itself");
    let stdout = child.stdout.take().expect("piped");
    let (tx, rx) = std::sync::mpsc::channel::<String>();
    let reader = std::thread::spawn(move || {
        for line in std::io::BufReader::new(stdout)
            .lines()
            .map_while(Result::ok)
        {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    // the child says `clipper-offsets MS` when its offsets are done, before it checks them
    let timed = rx.recv_timeout(std::time::Duration::from_secs_f64(limit_s));
    if !matches!(&timed, Ok(l) if l.starts_with("clipper-offsets ")) {
        let _ = child.kill();
        let _ = child.wait();
        let _ = reader.join();
        return None;
    }
    let report: Vec<String> = rx.iter().collect();
    let _ = child.wait();
    let _ = reader.join();
    let line = report
        .iter()
        .find_map(|l| l.strip_prefix("clipper-round "))
        .unwrap_or_else(|| panic!("no report from the Clipper2 round: {report:?}"));
    let w: Vec<&str> = line.split_whitespace().collect();
    Some(ChildRound {
        ms: w[0].parse().expect("ms"),
        verts: w[1].parse().expect("vertices"),
        arcs: w[2].parse().expect("arcs"),
        dev: w[3].parse().ok(),
    })
}

/// The child's side: one Clipper2 round of case `index`, its output checked, reported as
/// `clipper-round MS VERTICES ARCS DEVIATION` on stdout.
fn clipper_round(c: &Case) {
    let clip = Clipper;
    let set = clip.load(&c.boundaries);
    let (t, last) = measure(&clip, &set, &c.plan);
    println!("clipper-offsets {t}");
    use std::io::Write;
    let _ = std::io::stdout().flush();
    let cell = summarise(
        Measured {
            times: vec![t],
            last,
        },
        c.check,
    );
    println!(
        "clipper-round {} {} {} {}",
        cell.best,
        cell.verts,
        cell.arcs,
        cell.dev.map_or("-".to_string(), |d| d.to_string())
    );
}

fn summarise(mut m: Measured, check: Check) -> Cell {
    m.times.sort_by(f64::total_cmp);
    let rounds = m.times.len();
    let median = if rounds % 2 == 1 {
        m.times[rounds / 2]
    } else {
        0.5 * (m.times[rounds / 2 - 1] + m.times[rounds / 2])
    };
    let out = &m.last.last().expect("one offset at least").2;
    let (verts, arcs) = count(out);
    let dev = (check != Check::None).then(|| {
        m.last
            .iter()
            .filter_map(|(i, d, o)| deviation(check, i, o, *d))
            .fold(0.0, f64::max)
    });
    Cell {
        best: m.times[0],
        median,
        rounds,
        verts,
        arcs,
        dev,
    }
}

fn run_case(index: usize, c: &Case) -> Vec<Outcome> {
    let (ml, cav) = (Machlink, Cavalier);
    let sets = (ml.load(&c.boundaries), cav.load(&c.boundaries));
    let mut ms: [Option<Measured>; 2] = [None, None];
    let mut clip: Vec<ChildRound> = Vec::new();
    let mut stopped: Option<f64> = None;
    // each kernel's seconds of rounds so far
    let mut spent = [0.0f64; 3];
    let rounds = c.rounds.max(c.clipper_rounds);
    for round in 0..rounds {
        for j in 0..3 {
            let which = (round + j) % 3;
            let wanted = match which {
                2 => round < c.clipper_rounds && stopped.is_none(),
                _ => round < c.rounds,
            };
            if !wanted || (round > 0 && spent[which] >= c.budget_s) {
                continue;
            }
            if which == 2 {
                match clipper_round_in_child(index, c.clipper_limit_s) {
                    Some(r) => {
                        spent[2] += r.ms / 1e3;
                        clip.push(r);
                    }
                    None => stopped = Some(c.clipper_limit_s),
                }
                continue;
            }
            let (t, last) = match which {
                0 => measure(&ml, &sets.0, &c.plan),
                _ => measure(&cav, &sets.1, &c.plan),
            };
            spent[which] += t / 1e3;
            let e = ms[which].get_or_insert(Measured {
                times: Vec::new(),
                last: Vec::new(),
            });
            e.times.push(t);
            e.last = last;
        }
    }
    let mut out: Vec<Outcome> = ms
        .into_iter()
        .map(|m| Outcome::Measured(summarise(m.expect("one round at least"), c.check)))
        .collect();
    out.push(match (clip.last(), stopped) {
        (Some(last), _) => {
            let mut times: Vec<f64> = clip.iter().map(|r| r.ms).collect();
            times.sort_by(f64::total_cmp);
            let n = times.len();
            let median = if n % 2 == 1 {
                times[n / 2]
            } else {
                0.5 * (times[n / 2 - 1] + times[n / 2])
            };
            Outcome::Measured(Cell {
                best: times[0],
                median,
                rounds: n,
                verts: last.verts,
                arcs: last.arcs,
                dev: last.dev,
            })
        }
        (None, Some(after_s)) => Outcome::Stopped { after_s },
        (None, None) => unreachable!("Clipper2 runs one round at least"),
    });
    out
}

/// The measured cell, if the kernel was not stopped.
fn cell(x: &Outcome) -> Option<&Cell> {
    match x {
        Outcome::Measured(c) => Some(c),
        Outcome::Stopped { .. } => None,
    }
}

/// The gear's sizes, for its rows and the scaling block.
const GEAR_SIZES: [usize; 4] = [1_000, 10_000, 100_000, 1_000_000];
/// The distances (mm) of the 10k gear with islands, for its rows and the growth block.
const SERIES_MM: [f64; 4] = [2.0, 20.0, 200.0, 400.0];

/// A gear row's name (what `goal_lines` finds it by).
fn gear_row(n: usize, islands: bool) -> String {
    format!(
        "gear {n}{}, d = -2",
        if islands { " + 10 islands" } else { "" }
    )
}

/// A distance series row's name.
fn series_row(d: f64) -> String {
    format!("gear 10000 + 10 islands, d = -{d} (distance series)")
}

/// Milliseconds to three significant figures (the decade and distance ratios are read
/// from these: a 10k row's 1.5 ms rounded to a tenth was ±3 %).
fn fmt_ms(ms: f64) -> String {
    if ms < 1.0 {
        format!("{ms:.3}")
    } else if ms < 10.0 {
        format!("{ms:.2}")
    } else if ms < 100.0 {
        format!("{ms:.1}")
    } else {
        format!("{ms:.0}")
    }
}

fn fmt_time(c: &Outcome) -> String {
    match c {
        Outcome::Measured(c) if c.rounds > 1 => {
            format!(
                "{} / {} ({} rounds)",
                fmt_ms(c.best),
                fmt_ms(c.median),
                c.rounds
            )
        }
        Outcome::Measured(c) => format!("{} (1 round)", fmt_ms(c.best)),
        Outcome::Stopped { after_s } => format!("stopped after {after_s:.0} s (1 round)"),
    }
}

/// One input of a side-by-side block: its name, boundaries and distance.
struct Side {
    name: String,
    boundaries: Vec<Polyline>,
    d: f64,
}

/// machlink and cavalier_contours on every input of a block in each round, round-robin,
/// each timed offset right after an untimed one of the same, nothing else between: the
/// ratios between inputs (a decade of the gear, a distance against 2 mm) read from rows
/// run minutes apart moved by a tenth with whatever else the machine did meanwhile, as a
/// round after an idle wait runs slower. Returns each input's best times in ms,
/// (machlink, cavalier_contours).
fn side_by_side(inputs: &[Side], rounds: usize) -> Vec<(f64, f64)> {
    let (ml, cav) = (Machlink, Cavalier);
    let sets: Vec<(MlSet, CShape<f64>, Plan)> = inputs
        .iter()
        .map(|x| {
            (
                ml.load(&x.boundaries),
                cav.load(&x.boundaries),
                Plan::Once(x.d),
            )
        })
        .collect();
    let mut best = vec![(f64::INFINITY, f64::INFINITY); inputs.len()];
    for _ in 0..rounds {
        for (k, (m, c, plan)) in sets.iter().enumerate() {
            // (each timed offset follows an untimed one of the same input by the same
            // kernel: after the million-vertex gear, whose buffers and copies leave the
            // caches cold and the heap to sort out, the next round's 1k gear took ten
            // times its time, and the block read that instead of the gear)
            run_once(&ml, m, plan);
            let tm = run_once(&ml, m, plan).0;
            run_once(&cav, c, plan);
            let tc = run_once(&cav, c, plan).0;
            best[k] = (best[k].0.min(tm), best[k].1.min(tc));
        }
    }
    best
}

/// The gear of each size, with and without islands, at d = -2, each for every round (a
/// million's best of 3 against the 100k's best of 9 read its decade high: each size takes
/// as many rounds, as in the rows).
fn scaling_inputs(sizes: &[usize]) -> Vec<Side> {
    sizes
        .iter()
        .flat_map(|&n| [(n, false), (n, true)])
        .map(|(n, islands)| Side {
            name: format!("{n}{}", if islands { " + 10 islands" } else { "" }),
            boundaries: if islands {
                gear_with_islands(n)
            } else {
                vec![gear(n)]
            },
            d: -2.0,
        })
        .collect()
}

/// The 10k gear with islands at 2, 20, 200 and 400 mm.
fn distance_inputs() -> Vec<Side> {
    SERIES_MM
        .iter()
        .map(|&d| Side {
            name: format!("{d} mm"),
            boundaries: gear_with_islands(10_000),
            d: -d,
        })
        .collect()
}

/// A block's table: each input's best times and its ratio to `base(k)`, the input it is
/// read against (none: a dash).
fn print_side_by_side(
    title: &str,
    against: &str,
    inputs: &[Side],
    best: &[(f64, f64)],
    base: impl Fn(usize) -> Option<usize>,
) {
    println!("| {title} | machlink best (ms) | cavalier_contours best (ms) | machlink: {against} | cavalier_contours: {against} |");
    println!("|---|---:|---:|---:|---:|");
    for (k, (x, &(tm, tc))) in inputs.iter().zip(best).enumerate() {
        let ratio = |f: fn(&(f64, f64)) -> f64| {
            base(k).map_or("–".into(), |b| {
                format!("{:.1}×", f(&best[k]) / f(&best[b]))
            })
        };
        println!(
            "| {} | {} | {} | {} | {} |",
            x.name,
            fmt_ms(tm),
            fmt_ms(tc),
            ratio(|t| t.0),
            ratio(|t| t.1),
        );
    }
}

/// What the goals of scale and distance read from machlink's best times (by row name):
/// each decade of the gear rows, without and with islands, and the distance series'
/// growth from 2 mm. Rows the run left out are left out here.
fn goal_lines(best: &[(String, f64)]) -> Vec<String> {
    let of = |name: String| best.iter().find(|(n, _)| *n == name).map(|(_, t)| *t);
    let mut lines = Vec::new();
    for (label, islands) in [("gear", false), ("gear with islands", true)] {
        let decades: Vec<String> = GEAR_SIZES
            .windows(2)
            .filter_map(|w| {
                let t0 = of(gear_row(w[0], islands))?;
                let t1 = of(gear_row(w[1], islands))?;
                Some(format!("{} → {}: {:.1}×", w[0], w[1], t1 / t0))
            })
            .collect();
        if !decades.is_empty() {
            lines.push(format!(
                "decades from the rows above, {label} (machlink best ÷ best, goal ≤ 12×): {}",
                decades.join(", ")
            ));
        }
    }
    let series = |d: f64| of(series_row(d));
    if let Some(t2) = series(SERIES_MM[0]) {
        let growth: Vec<String> = SERIES_MM[1..]
            .iter()
            .filter_map(|&d| Some(format!("{d} mm {:.1}×", series(d)? / t2)))
            .collect();
        if !growth.is_empty() {
            lines.push(format!(
                "distance, gear 10000 + 10 islands (machlink best against 2 mm, goal ≤ 2×): {}",
                growth.join(", ")
            ));
        }
    }
    lines
}

/// Every row, 1M ones included (`quick` drops them when the table is printed, so a row's
/// index is the same for the child process whatever the options).
fn cases() -> Vec<Case> {
    let mut cases = Vec::new();
    for n in GEAR_SIZES {
        // (the 100k rows take as many rounds as the 10k ones: the decade between them is
        // read from best against best, and a best of 5 against one of 9 was not alike)
        let rounds = match n {
            ..=100_000 => 9,
            _ => 3,
        };
        // Clipper2 took ≈ 1.5 s a run at 100k (d = -2) and longer at 1M
        let clipper_rounds = match n {
            ..=10_000 => 5,
            10_001..=100_000 => 3,
            _ => 1,
        };
        for with_islands in [false, true] {
            cases.push(Case {
                name: gear_row(n, with_islands),
                boundaries: if with_islands {
                    gear_with_islands(n)
                } else {
                    vec![gear(n)]
                },
                plan: Plan::Once(-2.0),
                rounds,
                clipper_rounds,
                check: if n <= 100_000 {
                    Check::Full
                } else {
                    Check::None
                },
                budget_s: 30.0,
                clipper_limit_s: 240.0,
            });
        }
    }
    for d in SERIES_MM {
        cases.push(Case {
            name: series_row(d),
            boundaries: gear_with_islands(10_000),
            plan: Plan::Once(-d),
            rounds: 7,
            clipper_rounds: 3,
            check: Check::Full,
            // Clipper2 took 17 s a round at 400 mm
            budget_s: 30.0,
            clipper_limit_s: 120.0,
        });
    }
    cases.push(Case {
        name: "21 pocket passes of gear 10000 + 10 islands, each from the original, d = -20 … -420"
            .into(),
        boundaries: gear_with_islands(10_000),
        plan: Plan::FromOriginal((1..=21).map(|k| -20.0 * k as f64).collect()),
        rounds: 5,
        // Clipper2 took 207 s for its one round
        clipper_rounds: 1,
        check: Check::Full,
        budget_s: 30.0,
        clipper_limit_s: 400.0,
    });
    cases.push(Case {
        name: "21 pocket passes of gear 10000 + 10 islands, each from the previous, d = -20".into(),
        boundaries: gear_with_islands(10_000),
        plan: Plan::Incremental(-20.0, 21),
        rounds: 9,
        clipper_rounds: 3,
        check: Check::Full,
        budget_s: 30.0,
        clipper_limit_s: 120.0,
    });
    let inr = |n: usize| 10.0 * (std::f64::consts::PI / n as f64).cos();
    cases.push(Case {
        name: "dense circle 30000, r = 10, to 1e-3 of its inradius".into(),
        boundaries: vec![dense_circle(30_000)],
        plan: Plan::Once(-(inr(30_000) - 1e-3)),
        rounds: 9,
        // an earlier Clipper2 did not finish this one within minutes
        clipper_rounds: 1,
        check: Check::Distance,
        budget_s: 30.0,
        clipper_limit_s: 60.0,
    });
    cases.push(Case {
        name: "dense circle 100000, r = 10, d = -9.999".into(),
        boundaries: vec![dense_circle(100_000)],
        plan: Plan::Once(-9.999),
        rounds: 9,
        clipper_rounds: 1,
        check: Check::Distance,
        budget_s: 30.0,
        clipper_limit_s: 60.0,
    });
    cases
}

fn main() {
    // as the planner's process does (offset_core::heap); the anchors run under it alike
    offset_core::heap::hold_freed_memory();
    let args: Vec<String> = std::env::args().collect();
    if let Some(i) = args.iter().position(|a| a == "clipper-round") {
        let index: usize = args
            .get(i + 1)
            .and_then(|s| s.parse().ok())
            .expect("clipper-round INDEX");
        clipper_round(&cases()[index]);
        return;
    }
    let quick = args.iter().any(|a| a == "quick");
    let forced: Option<usize> = args
        .iter()
        .position(|a| a == "rounds")
        .and_then(|i| args.get(i + 1))
        .and_then(|s| s.parse().ok());
    let only: Option<String> = args
        .iter()
        .position(|a| a == "only")
        .and_then(|i| args.get(i + 1))
        .cloned();
    let started = Instant::now();
    println!("load average (1 min) at the start: {}", load_average());
    println!();
    println!("| case | machlink (ms, best / median, rounds) | cavalier_contours 0.9 | Clipper2 0.6 | cavalier_contours ÷ machlink (best, median) | output vertices (arcs): machlink / cavalier_contours / Clipper2 | worst deviation (mm): machlink / cavalier_contours / Clipper2 | load |");
    println!("|---|---:|---:|---:|---:|---:|---:|---:|");
    // machlink's best time per row run, for the goals' lines at the end
    let mut machlink_best: Vec<(String, f64)> = Vec::new();
    for (index, mut c) in cases().into_iter().enumerate() {
        if quick && c.name.starts_with("gear 1000000") {
            continue;
        }
        if only.as_ref().is_some_and(|o| !c.name.contains(o.as_str())) {
            continue;
        }
        if let Some(r) = forced {
            c.rounds = r;
            c.clipper_rounds = c.clipper_rounds.min(r);
        }
        let cells = run_case(index, &c);
        if let Some(m) = cell(&cells[0]) {
            machlink_best.push((c.name.clone(), m.best));
        }
        let dev = |x: &Outcome| match cell(x) {
            Some(Cell { dev: Some(d), .. }) => format!("{d:.1e}"),
            Some(_) => "not checked".into(),
            None => "–".into(),
        };
        let ratio = match (cell(&cells[0]), cell(&cells[1])) {
            (Some(m), Some(cv)) => {
                format!("{:.2}×, {:.2}×", cv.best / m.best, cv.median / m.median)
            }
            _ => "–".into(),
        };
        let outs =
            |x: &Outcome| cell(x).map_or("–".into(), |c| format!("{} ({})", c.verts, c.arcs));
        println!(
            "| {} | {} | {} | {} | {} | {} / {} / {} | {} / {} / {} | {} |",
            c.name,
            fmt_time(&cells[0]),
            fmt_time(&cells[1]),
            fmt_time(&cells[2]),
            ratio,
            outs(&cells[0]),
            outs(&cells[1]),
            outs(&cells[2]),
            dev(&cells[0]),
            dev(&cells[1]),
            dev(&cells[2]),
            load_average(),
        );
    }
    println!();
    for line in goal_lines(&machlink_best) {
        println!("{line}");
    }
    println!();
    let rounds = forced.unwrap_or(9);
    if only.is_none() || only.as_deref() == Some("scaling") {
        let sizes = if quick {
            &GEAR_SIZES[..3]
        } else {
            &GEAR_SIZES[..]
        };
        let inputs = scaling_inputs(sizes);
        println!(
            "scaling: every size in each round, {rounds} rounds; load average (1 min): {}",
            load_average()
        );
        println!();
        let best = side_by_side(&inputs, rounds);
        // (inputs alternate without and with islands: the decade before is two back)
        print_side_by_side("gear, d = -2", "the decade before", &inputs, &best, |k| {
            k.checked_sub(2)
        });
        println!();
    }
    if only.is_none() || only.as_deref() == Some("growth") {
        let inputs = distance_inputs();
        println!(
            "growth with distance: every distance in each round, {rounds} rounds; load average (1 min): {}",
            load_average()
        );
        println!();
        let best = side_by_side(&inputs, rounds);
        print_side_by_side(
            "gear 10000 + 10 islands, shrunk by",
            "against 2 mm",
            &inputs,
            &best,
            |k| (k > 0).then_some(0),
        );
        println!();
    }
    println!(
        "the whole run: {:.0} s; load average (1 min) at the end: {}",
        started.elapsed().as_secs_f64(),
        load_average()
    );
}
