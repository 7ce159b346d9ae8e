//! Shared test helpers: a region offset built on Clipper2 (for comparison and for testing
//! the pocket's pass logic on its own), and a coverage and gouge check by rasterising.
#![allow(dead_code)]

use clipper2::{EndType, JoinType, Milli, Paths};
use offset_core::geom::{Point, Polyline, Region, Segment, Shape};
use offset_core::offset::OffsetError;
use offset_core::toolpath::{Move, Toolpath, P3};

/// The region's boundaries as polygons, arcs cut into chords within `tol`.
pub fn polygons(r: &Region, tol: f64) -> Vec<Vec<(f64, f64)>> {
    r.boundaries()
        .map(|pl| {
            let mut pts = Vec::new();
            for s in pl.segments() {
                match s {
                    Segment::Line { a, .. } => pts.push((a.x, a.y)),
                    Segment::Arc { radius, .. } => {
                        let step = 2.0 * (1.0 - tol / radius).clamp(-1.0, 1.0).acos();
                        let k = ((s.sweep().abs() / step.max(1e-3)).ceil() as usize).max(1);
                        for q in 0..k {
                            let p = s.point_at(q as f64 / k as f64);
                            pts.push((p.x, p.y));
                        }
                    }
                }
            }
            pts
        })
        .collect()
}

/// Offsets a region with Clipper2 (round joins, 1 µm grid), regrouped into regions.
pub fn clipper_offset(r: &Region, d: f64, tol: f64) -> Result<Vec<Region>, OffsetError> {
    let paths: Paths<Milli> = polygons(r, tol).into();
    let out = paths.inflate(d, JoinType::Round, EndType::Polygon, 2.0);
    let pls: Vec<Polyline> = out
        .iter()
        .map(|p| {
            let pts: Vec<Point> = p.iter().map(|q| Point::new(q.x(), q.y())).collect();
            Polyline::from_points(&pts, true)
        })
        .filter(|p| p.len() >= 3)
        .collect();
    Ok(Shape::new(pls).regions())
}

/// What a rasterised check of a tool path found.
#[derive(Debug)]
pub struct Coverage {
    /// Cells the tool can reach (some disc of radius r inside the pocket holds them) that
    /// the path never swept, with a cell where it happened.
    pub uncut: usize,
    pub first_uncut: Option<Point>,
    /// Points of cutting moves closer than r - tol to a wall or an island, or outside.
    pub gouges: usize,
    pub first_gouge: Option<Point>,
    pub cells: usize,
}

/// Rasterises the pocket `region` at `h` mm and checks the path's cutting moves at depth
/// `z`: every cell the tool could reach must be swept by the tool's disc (radius `r`),
/// and no cutting move may bring the tool within `r - tol` of a wall or an island.
pub fn check_coverage(
    region: &Region,
    tp: &Toolpath,
    r: f64,
    z: f64,
    h: f64,
    tol: f64,
) -> Coverage {
    let b = region.bounds();
    let nx = ((b.width() / h).ceil() as usize) + 1;
    let ny = ((b.height() / h).ceil() as usize) + 1;
    let cell = |i: usize, j: usize| {
        Point::new(
            b.min.x + (i as f64 + 0.5) * h,
            b.min.y + (j as f64 + 0.5) * h,
        )
    };
    let walls = |p: Point| {
        region
            .boundaries()
            .map(|w| w.distance_to(p))
            .fold(f64::INFINITY, f64::min)
    };
    // distance to the walls for every cell inside the pocket (NaN outside)
    let mut wd = vec![f64::NAN; nx * ny];
    for j in 0..ny {
        for i in 0..nx {
            let p = cell(i, j);
            if region.contains(p) {
                wd[j * nx + i] = walls(p);
            }
        }
    }
    // sweep: chords of the cutting moves at depth z
    let mut swept = vec![false; nx * ny];
    let mut gouges = 0;
    let mut first_gouge = None;
    let mut chords: Vec<(P3, P3)> = Vec::new();
    tp.walk(P3::default(), |from, m, to| {
        let cutting = matches!(m, Move::Linear { .. } | Move::Arc { .. });
        if !cutting || from.z < z - 1e-9 || to.z < z - 1e-9 {
            return;
        }
        let mut one = Toolpath::new("");
        one.push(m.clone());
        let pts = one.sample(from, h);
        for w in pts.windows(2) {
            chords.push((w[0], w[1]));
        }
    });
    for &(a, c) in &chords {
        // gouge check on every cutting move below the stock top
        if a.z < 0.0 || c.z < 0.0 {
            for p in [a.xy(), c.xy()] {
                if !region.contains(p) || walls(p) < r - tol {
                    gouges += 1;
                    first_gouge.get_or_insert(p);
                }
            }
        }
        if (a.z - z).abs() > 1e-9 || (c.z - z).abs() > 1e-9 {
            continue;
        }
        let seg = Segment::Line {
            a: a.xy(),
            b: c.xy(),
        };
        let sb = seg.bounds();
        let i0 = (((sb.min.x - r - b.min.x) / h).floor().max(0.0)) as usize;
        let j0 = (((sb.min.y - r - b.min.y) / h).floor().max(0.0)) as usize;
        let i1 = ((((sb.max.x + r - b.min.x) / h).ceil()) as usize).min(nx - 1);
        let j1 = ((((sb.max.y + r - b.min.y) / h).ceil()) as usize).min(ny - 1);
        for j in j0..=j1 {
            for i in i0..=i1 {
                if !swept[j * nx + i] && seg.distance_to(cell(i, j)) <= r {
                    swept[j * nx + i] = true;
                }
            }
        }
    }
    // uncut cells: inside, not swept, yet reachable by a tool disc that fits
    let mut uncut = 0;
    let mut first_uncut = None;
    let mut cells = 0;
    let reach = ((r / h).ceil()) as isize;
    for j in 0..ny {
        for i in 0..nx {
            let d = wd[j * nx + i];
            if d.is_nan() {
                continue;
            }
            cells += 1;
            if swept[j * nx + i] {
                continue;
            }
            // a centre cell within r - h whose disc (r + h for the grid) stays inside
            let mut reachable = false;
            'search: for dj in -reach..=reach {
                for di in -reach..=reach {
                    let (ci, cj) = (i as isize + di, j as isize + dj);
                    if ci < 0 || cj < 0 || ci >= nx as isize || cj >= ny as isize {
                        continue;
                    }
                    let k = cj as usize * nx + ci as usize;
                    let cd = wd[k];
                    if !cd.is_nan()
                        && cd >= r + h
                        && cell(ci as usize, cj as usize).dist(cell(i, j)) <= r - h
                    {
                        reachable = true;
                        break 'search;
                    }
                }
            }
            if reachable {
                uncut += 1;
                first_uncut.get_or_insert(cell(i, j));
            }
        }
    }
    Coverage {
        uncut,
        first_uncut,
        gouges,
        first_gouge,
        cells,
    }
}

/// How a tool path goes down below the stock top (Z 0).
#[derive(Debug, Default)]
pub struct Descents {
    /// The steepest descent of a move that also moves across (dz per mm across), and where.
    pub steepest: f64,
    pub steepest_at: Option<P3>,
    /// Straight-down moves that cut into the material: ones the path follows with anything
    /// but a further descent (a straight-down move followed by a ramp or helix is the
    /// approach through air to the floor of the last pass, where the entry starts).
    pub plunges: usize,
    pub first_plunge: Option<P3>,
    /// Moves that go down while moving across (ramps, helices).
    pub ramps: usize,
}

/// Every descent below the stock top, sorted into ramps (with their steepness) and plunges.
pub fn descents(tp: &Toolpath) -> Descents {
    let mut moves: Vec<(P3, Move, P3)> = Vec::new();
    tp.walk(P3::default(), |from, m, to| {
        if matches!(
            m,
            Move::Linear { .. } | Move::Arc { .. } | Move::Rapid { .. }
        ) {
            moves.push((from, m.clone(), to));
        }
    });
    let mut d = Descents::default();
    for (i, (from, m, to)) in moves.iter().enumerate() {
        if !(to.z < from.z - 1e-12 && to.z < -1e-12) {
            continue;
        }
        let xy = match m {
            Move::Arc { center, ccw, .. } => {
                offset_core::toolpath::arc_segment(from.xy(), to.xy(), *center, *ccw).length()
            }
            _ => from.xy().dist(to.xy()),
        };
        if xy < 1e-9 {
            let next_descends = moves.get(i + 1).is_some_and(|(f, _, t)| t.z < f.z - 1e-12);
            if !next_descends {
                d.plunges += 1;
                d.first_plunge.get_or_insert(*to);
            }
            continue;
        }
        d.ramps += 1;
        let s = (from.z - to.z) / xy;
        if s > d.steepest {
            d.steepest = s;
            d.steepest_at = Some(*to);
        }
    }
    d
}

/// The arcs of a tool path that descend (helix turns): (centre, radius).
pub fn descending_arcs(tp: &Toolpath) -> Vec<(Point, f64)> {
    let mut out = Vec::new();
    tp.walk(P3::default(), |from, m, to| {
        if let Move::Arc { center, .. } = m {
            if to.z < from.z - 1e-12 {
                out.push((*center, from.xy().dist(*center)));
            }
        }
    });
    out
}

/// The first arc that does not start where the tool is (as far from its centre as its end
/// lies), if any: a move planned from the wrong place.
pub fn disjoint_arc(tp: &Toolpath) -> Option<(P3, P3, Point)> {
    let mut bad = None;
    tp.walk(P3::default(), |from, m, to| {
        if let Move::Arc { center, .. } = m {
            let (r0, r1) = (from.xy().dist(*center), to.xy().dist(*center));
            if (r0 - r1).abs() > 1e-6 * (1.0 + r0) && bad.is_none() {
                bad = Some((from, to, *center));
            }
        }
    });
    bad
}
