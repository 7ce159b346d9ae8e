//! Chaining loose pieces (lines, arcs, open polylines) into contours, and the checks importers report: open chains, gaps, duplicates, self-intersections.

use crate::geom::{Point, Polyline, Segment};
use std::collections::HashMap;

/// Joins open pieces end to end where their ends lie within `tol` of each other (pieces are
/// reversed as needed); a chain whose ends meet is closed. Closed pieces pass through.
/// Open chains and near misses (gaps up to 100 × `tol`) and duplicate pieces are reported
/// in `warnings` with their location.
pub fn chain(pieces: Vec<Polyline>, tol: f64, warnings: &mut Vec<String>) -> Vec<Polyline> {
    let tol = if tol.is_finite() && tol > 0.0 {
        tol
    } else {
        1e-6
    };
    let mut out = Vec::new();
    let mut open: Vec<Polyline> = Vec::new();
    for p in pieces {
        if p.len() < 2 {
            continue;
        }
        if p.closed {
            out.push(p);
        } else {
            open.push(p);
        }
    }
    // drop exact duplicates (same ends either way and same midpoint)
    let mut seen: HashMap<[i64; 6], usize> = HashMap::new();
    let key = |p: Point| ((p.x / tol).round() as i64, (p.y / tol).round() as i64);
    let mut keep = vec![true; open.len()];
    for (i, p) in open.iter().enumerate() {
        let a = p.vertices[0].pos();
        let b = p.vertices[p.len() - 1].pos();
        let mid = p.segment(p.segment_count() / 2).point_at(0.5);
        let (ka, kb, km) = (key(a), key(b), key(mid));
        let (lo, hi) = if ka <= kb { (ka, kb) } else { (kb, ka) };
        let k = [lo.0, lo.1, hi.0, hi.1, km.0, km.1];
        if let Some(&j) = seen.get(&k) {
            if p.len() == open[j].len() {
                keep[i] = false;
                warnings.push(format!(
                    "duplicate piece from ({:.4}, {:.4}) to ({:.4}, {:.4}) dropped",
                    a.x, a.y, b.x, b.y
                ));
                continue;
            }
        }
        seen.insert(k, i);
    }
    let open: Vec<Polyline> = open
        .into_iter()
        .zip(keep)
        .filter_map(|(p, k)| k.then_some(p))
        .collect();

    // ends in a grid of cells `tol` wide: (piece, is_end), behind the number of leading
    // entries already used (where many ends meet, skipping those keeps chaining linear)
    let cell = |p: Point| ((p.x / tol).floor() as i64, (p.y / tol).floor() as i64);
    type Grid = HashMap<(i64, i64), (usize, Vec<(usize, bool)>)>;
    let mut grid: Grid = HashMap::new();
    let end_of = |p: &Polyline, is_end: bool| {
        if is_end {
            p.vertices[p.len() - 1].pos()
        } else {
            p.vertices[0].pos()
        }
    };
    for (i, p) in open.iter().enumerate() {
        for e in [false, true] {
            grid.entry(cell(end_of(p, e))).or_default().1.push((i, e));
        }
    }
    let mut used = vec![false; open.len()];
    // the nearest unused end within `tol` of `at` (the first found of equally near ones)
    let find = |at: Point, used: &Vec<bool>, grid: &mut Grid| {
        let (cx, cy) = cell(at);
        let mut best: Option<(usize, bool, f64)> = None;
        for dx in -1..=1 {
            for dy in -1..=1 {
                if let Some((skip, v)) =
                    grid.get_mut(&(cx.saturating_add(dx), cy.saturating_add(dy)))
                {
                    while *skip < v.len() && used[v[*skip].0] {
                        *skip += 1;
                    }
                    for &(i, e) in &v[*skip..] {
                        if used[i] {
                            continue;
                        }
                        let d = end_of(&open[i], e).dist(at);
                        if d <= tol && best.is_none_or(|b| d < b.2) {
                            best = Some((i, e, d));
                            if d == 0.0 {
                                return best; // none can be nearer
                            }
                        }
                    }
                }
            }
        }
        best
    };
    let mut chains: Vec<Polyline> = Vec::new();
    for start in 0..open.len() {
        if used[start] {
            continue;
        }
        used[start] = true;
        let mut c = open[start].clone();
        for _side in 0..2 {
            loop {
                let at = c.vertices[c.len() - 1].pos();
                if c.vertices[0].pos().dist(at) <= tol && c.segment_count() >= 2 {
                    break;
                }
                let Some((i, is_end, _)) = find(at, &used, &mut grid) else {
                    break;
                };
                used[i] = true;
                let next = if is_end {
                    open[i].reversed()
                } else {
                    open[i].clone()
                };
                c.vertices.pop();
                c.vertices.extend_from_slice(&next.vertices);
            }
            c = c.reversed();
        }
        let (a, b) = (c.vertices[0].pos(), c.vertices[c.len() - 1].pos());
        if a.dist(b) <= tol && c.segment_count() >= 2 {
            c.vertices.pop();
            c.closed = true;
        }
        chains.push(c);
    }
    // report what stayed open, and gaps between open ends
    let open_ends: Vec<(usize, Point)> = chains
        .iter()
        .enumerate()
        .filter(|(_, c)| !c.closed)
        .flat_map(|(i, c)| [(i, c.vertices[0].pos()), (i, c.vertices[c.len() - 1].pos())])
        .collect();
    // open ends in a grid of cells as wide as the largest gap reported
    let gap_cell = |p: Point| {
        (
            (p.x / (100.0 * tol)).floor() as i64,
            (p.y / (100.0 * tol)).floor() as i64,
        )
    };
    let mut gap_grid: HashMap<(i64, i64), Vec<usize>> = HashMap::new();
    for (k, &(_, q)) in open_ends.iter().enumerate() {
        gap_grid.entry(gap_cell(q)).or_default().push(k);
    }
    for (i, c) in chains.iter().enumerate() {
        if !c.closed {
            let (a, b) = (c.vertices[0].pos(), c.vertices[c.len() - 1].pos());
            warnings.push(format!(
                "open contour of {} segments from ({:.4}, {:.4}) to ({:.4}, {:.4})",
                c.segment_count(),
                a.x,
                a.y,
                b.x,
                b.y
            ));
            // the open ends near a or b, in the order of open_ends
            let mut near: Vec<usize> = Vec::new();
            for p in [a, b] {
                let (cx, cy) = gap_cell(p);
                for dx in -1..=1 {
                    for dy in -1..=1 {
                        if let Some(v) =
                            gap_grid.get(&(cx.saturating_add(dx), cy.saturating_add(dy)))
                        {
                            near.extend(v);
                        }
                    }
                }
            }
            near.sort_unstable();
            near.dedup();
            for k in near {
                let (j, q) = open_ends[k];
                if j != i {
                    for p in [a, b] {
                        let d = p.dist(q);
                        if d > tol && d <= 100.0 * tol && (i, p.x) < (j, q.x) {
                            warnings.push(format!(
                                "gap of {d:.6} mm between ({:.4}, {:.4}) and ({:.4}, {:.4})",
                                p.x, p.y, q.x, q.y
                            ));
                        }
                    }
                }
            }
        }
    }
    out.extend(chains);
    out
}

/// Where a polyline crosses itself: the first few crossing points of its segments (arcs
/// checked as fine chords), or an empty list. Polylines of more than 100 000 chords are not
/// checked.
pub fn self_intersections(pl: &Polyline, max: usize) -> Vec<Point> {
    let mut chords: Vec<(Point, Point, usize)> = Vec::new();
    for (i, s) in pl.segments().enumerate() {
        match s {
            Segment::Line { a, b } => chords.push((a, b, i)),
            Segment::Arc { .. } => {
                let k = ((s.sweep().abs() / 0.1).ceil() as usize).clamp(1, 64);
                for q in 0..k {
                    chords.push((
                        s.point_at(q as f64 / k as f64),
                        s.point_at((q + 1) as f64 / k as f64),
                        i,
                    ));
                }
            }
        }
    }
    if chords.len() > 100_000 {
        return Vec::new();
    }
    let nseg = pl.segment_count();
    let mut order: Vec<usize> = (0..chords.len()).collect();
    let minx = |c: &(Point, Point, usize)| c.0.x.min(c.1.x);
    let maxx = |c: &(Point, Point, usize)| c.0.x.max(c.1.x);
    order.sort_by(|&a, &b| minx(&chords[a]).total_cmp(&minx(&chords[b])));
    let mut found = Vec::new();
    for (k, &a) in order.iter().enumerate() {
        let ca = chords[a];
        for &b in &order[k + 1..] {
            let cb = chords[b];
            if minx(&cb) > maxx(&ca) {
                break;
            }
            // chords of one segment, or of neighbouring segments, meet at their shared ends
            let (sa, sb) = (ca.2, cb.2);
            let adjacent = sa == sb
                || (sa + 1) % nseg.max(1) == sb && (pl.closed || sa + 1 < nseg)
                || (sb + 1) % nseg.max(1) == sa && (pl.closed || sb + 1 < nseg);
            if adjacent {
                continue;
            }
            if let Some(p) = crossing(ca.0, ca.1, cb.0, cb.1) {
                found.push(p);
                if found.len() >= max {
                    return found;
                }
            }
        }
    }
    found
}

/// The crossing point of segments ab and cd, if they cross or touch.
fn crossing(a: Point, b: Point, c: Point, d: Point) -> Option<Point> {
    let r = b - a;
    let s = d - c;
    let den = r.cross(s);
    if den.abs() < 1e-15 {
        return None;
    }
    let t = (c - a).cross(s) / den;
    let u = (c - a).cross(r) / den;
    ((0.0..=1.0).contains(&t) && (0.0..=1.0).contains(&u)).then(|| a + r * t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::Vertex;

    #[test]
    fn loose_lines_chain_into_a_closed_square_in_any_direction() {
        let l = |a: (f64, f64), b: (f64, f64)| {
            Polyline::new(
                vec![Vertex::new(a.0, a.1, 0.0), Vertex::new(b.0, b.1, 0.0)],
                false,
            )
        };
        let pieces = vec![
            l((0.0, 0.0), (1.0, 0.0)),
            l((1.0, 1.0), (1.0, 0.0)), // reversed
            l((0.0, 1.0), (0.0, 0.0)),
            l((1.0, 1.0), (0.0, 1.0 + 1e-7)),
        ];
        let mut w = Vec::new();
        let c = chain(pieces, 1e-6, &mut w);
        assert_eq!(c.len(), 1);
        assert!(c[0].closed && c[0].len() == 4, "{c:?}");
        assert!((c[0].area().abs() - 1.0).abs() < 1e-6);
        assert!(w.is_empty(), "{w:?}");
    }

    #[test]
    fn a_bow_tie_crosses_itself_in_the_middle() {
        let p = Polyline::from_points(
            &[
                Point::new(0.0, 0.0),
                Point::new(2.0, 2.0),
                Point::new(2.0, 0.0),
                Point::new(0.0, 2.0),
            ],
            true,
        );
        let x = self_intersections(&p, 5);
        assert_eq!(x.len(), 1);
        assert!(x[0].dist(Point::new(1.0, 1.0)) < 1e-12);
        assert!(self_intersections(&Polyline::circle(Point::default(), 3.0), 5).is_empty());
    }
}
