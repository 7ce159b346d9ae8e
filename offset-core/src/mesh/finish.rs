//! Finishing (finish3d): raster passes of drop-cutter locations over a mesh at a
//! step-over, each row sampled adaptively and fitted with lines within the tolerance.
//!
//! Every cutter location is a drop-cutter height, the lowest at which the cutter touches
//! no triangle, so the points are gouge-free by construction. Between two locations the
//! path is straight; a row is sampled at a quarter of the tool radius and each interval
//! halved (down to the tolerance in length) while the drop-cutter height at its middle
//! lies more than a tenth of the tolerance above the chord (the chord would cut in) or
//! more than the tolerance below it (it would leave material). The fit then drops the
//! locations that lie under a longer chord by no more than the tolerance and not above it
//! at all, so fitting never cuts deeper than the sampled locations.

use super::dropcutter::{Cutter, CutterShape, DropCutter};
use super::{Mesh, MeshError, V3};
use crate::ops::Stepover;
use crate::toolpath::{Move, Tool, ToolKind, Toolpath};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Everything a drop-cutter finish needs besides the mesh.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Finish3dParams {
    pub cutter: Cutter,
    /// The tool's number in the machine's magazine.
    #[serde(default = "one")]
    pub tool_number: u32,
    /// Distance between neighbouring rows.
    pub stepover: Stepover,
    /// Direction of the rows, degrees from +X counter-clockwise (0: rows along X).
    #[serde(default)]
    pub angle: f64,
    /// Geometric tolerance of sampling and line fitting, mm.
    pub tolerance: f64,
    /// Cutting feed, mm/min.
    pub feed: f64,
    /// Plunge feed, mm/min.
    pub plunge_feed: f64,
    /// Height of rapids above the stock top, mm.
    pub safe_z: f64,
    /// The stock top, Z in the mesh's frame (None: the mesh's highest Z).
    #[serde(default)]
    pub stock_top: Option<f64>,
    /// Spindle speed, rpm (0 leaves the spindle alone).
    pub spindle_rpm: f64,
    /// Link each row to the next at the boundary, cutting back the other way (true), or
    /// retract and start every row from the same side (false).
    #[serde(default = "yes")]
    pub zigzag: bool,
    /// The area the tool centre covers, [x_min, y_min, x_max, y_max] (None: the mesh's
    /// plan-view extents).
    #[serde(default)]
    pub area: Option<[f64; 4]>,
    /// The lowest tip height, where nothing is under the cutter (None: the mesh's lowest Z).
    #[serde(default)]
    pub floor: Option<f64>,
}

fn one() -> u32 {
    1
}
fn yes() -> bool {
    true
}

impl Default for Finish3dParams {
    fn default() -> Self {
        Finish3dParams {
            cutter: Cutter::ball(6.0),
            tool_number: 1,
            stepover: Stepover::Percent(10.0),
            angle: 0.0,
            tolerance: 0.01,
            feed: 1200.0,
            plunge_feed: 300.0,
            safe_z: 5.0,
            stock_top: None,
            spindle_rpm: 12000.0,
            zigzag: true,
            area: None,
            floor: None,
        }
    }
}

impl Finish3dParams {
    fn check(&self) -> Result<(), MeshError> {
        self.cutter.check()?;
        let bad = |what: &str, v: f64| {
            MeshError::BadParam(format!("{what} must be a positive number, got {v}"))
        };
        let s = self.stepover.mm(self.cutter.diameter);
        for (v, what) in [
            (s, "the step-over"),
            (self.tolerance, "the tolerance"),
            (self.feed, "the feed"),
            (self.plunge_feed, "the plunge feed"),
            (self.safe_z, "the safe Z"),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(bad(what, v));
            }
        }
        if s > self.cutter.diameter {
            return Err(MeshError::BadParam(format!(
                "the step-over {s} mm is more than the cutter diameter {} mm: ridges would stay between rows",
                self.cutter.diameter
            )));
        }
        if !self.angle.is_finite() {
            return Err(MeshError::BadParam(format!(
                "the row angle must be a number, got {}",
                self.angle
            )));
        }
        Ok(())
    }
}

/// The tool a 3D path was planned for, as the Toolpath IR names it (a bull cutter is
/// flat-ended there; the comment at the path's start says its corner radius).
pub fn tool_of(c: &Cutter, number: u32) -> Tool {
    Tool {
        number,
        diameter: c.diameter,
        kind: match c.shape {
            CutterShape::Ball => ToolKind::BallEnd,
            _ => ToolKind::FlatEnd,
        },
    }
}

/// The cutter in words, for comments and messages.
pub fn describe(c: &Cutter) -> String {
    match c.shape {
        CutterShape::Ball => format!("ball d{}", c.diameter),
        CutterShape::Flat => format!("flat d{}", c.diameter),
        CutterShape::Bull => format!("bull d{} r{}", c.diameter, c.corner_radius),
    }
}

/// The rows of a raster over `area` (tool-centre extents) at `angle` degrees, `step` apart,
/// each clipped to the area: (start, end) in plan view, every other one reversed when
/// `zigzag`.
pub fn raster_rows(area: [f64; 4], angle: f64, step: f64, zigzag: bool) -> Vec<[(f64, f64); 2]> {
    let (dx, dy) = (angle.to_radians().cos(), angle.to_radians().sin());
    let (nx, ny) = (-dy, dx);
    let corners = [
        (area[0], area[1]),
        (area[2], area[1]),
        (area[2], area[3]),
        (area[0], area[3]),
    ];
    let across: Vec<f64> = corners.iter().map(|&(x, y)| x * nx + y * ny).collect();
    let (t0, t1) = (
        across.iter().copied().fold(f64::INFINITY, f64::min),
        across.iter().copied().fold(f64::NEG_INFINITY, f64::max),
    );
    let n = (((t1 - t0) / step).ceil() as usize).max(1);
    let mut rows = Vec::with_capacity(n + 1);
    for k in 0..=n {
        let t = t0 + (t1 - t0) * k as f64 / n as f64;
        // the line {p : p·n = t} clipped to the rectangle (Liang–Barsky on p = o + s d)
        let o = (nx * t, ny * t);
        let (mut s0, mut s1) = (f64::NEG_INFINITY, f64::INFINITY);
        let mut empty = false;
        for (dc, oc, lo, hi) in [(dx, o.0, area[0], area[2]), (dy, o.1, area[1], area[3])] {
            if dc.abs() < 1e-15 {
                if oc < lo - 1e-9 || oc > hi + 1e-9 {
                    empty = true;
                }
            } else {
                let (a, b) = ((lo - oc) / dc, (hi - oc) / dc);
                s0 = s0.max(a.min(b));
                s1 = s1.min(a.max(b));
            }
        }
        if empty || s1 < s0 {
            continue;
        }
        let a = (o.0 + s0 * dx, o.1 + s0 * dy);
        let b = (o.0 + s1 * dx, o.1 + s1 * dy);
        let flip = zigzag && rows.len() % 2 == 1;
        rows.push(if flip { [b, a] } else { [a, b] });
    }
    rows
}

/// Drop-cutter locations along the straight plan-view line a→b, sampled adaptively (see
/// the module's note), as points.
pub fn sample_line(dc: &DropCutter, a: (f64, f64), b: (f64, f64), floor: f64, tol: f64) -> Vec<V3> {
    let len = ((b.0 - a.0).powi(2) + (b.1 - a.1).powi(2)).sqrt();
    let at = |s: f64| {
        let t = if len > 0.0 { s / len } else { 0.0 };
        let (x, y) = (a.0 + (b.0 - a.0) * t, a.1 + (b.1 - a.1) * t);
        V3::new(x, y, dc.drop(x, y, floor))
    };
    let h0 = (dc.cutter().radius() / 4.0).max(tol);
    let n = ((len / h0).ceil() as usize).max(1);
    let min_step = tol.max(1e-6);
    let mut out = vec![at(0.0)];
    let mut stack: Vec<(f64, V3, f64, V3)> = Vec::new();
    for i in 0..n {
        let (s0, s1) = (len * i as f64 / n as f64, len * (i + 1) as f64 / n as f64);
        let p0 = *out.last().unwrap();
        let p1 = at(s1);
        stack.push((s0, p0, s1, p1));
        while let Some((sa, pa, sb, pb)) = stack.pop() {
            if sb - sa > min_step {
                let sm = 0.5 * (sa + sb);
                let pm = at(sm);
                // the middle and the quarters (a kink between two samples can hide
                // from the middle alone)
                // heights off the chord, measured square to it (on a steep wall a
                // sliver of the chord's length is a long way in height)
                let slope = (pb.z - pa.z) / (sb - sa);
                let square = 1.0 / (1.0 + slope * slope).sqrt();
                let off = |q: V3, t: f64| (q.z - (pa.z + (pb.z - pa.z) * t)) * square;
                let bad = |d: f64| d > 0.1 * tol || d < -tol;
                if bad(off(pm, 0.5))
                    || bad(off(at(0.75 * sa + 0.25 * sb), 0.25))
                    || bad(off(at(0.25 * sa + 0.75 * sb), 0.75))
                {
                    // the right half waits under the left one
                    stack.push((sm, pm, sb, pb));
                    stack.push((sa, pa, sm, pm));
                    continue;
                }
            }
            out.push(pb);
        }
    }
    out
}

/// Keeps the points of a straight-in-plan row that a line fit needs: a point goes when
/// the chord over it lies above it by no more than `tol` (never below it).
pub fn fit_row(pts: &[V3], tol: f64) -> Vec<V3> {
    if pts.len() <= 2 {
        return pts.to_vec();
    }
    let mut out = vec![pts[0]];
    let mut i = 0;
    while i < pts.len() - 1 {
        let mut j = i + 1;
        // extend the chord from i as far as every point under it fits
        while j + 1 < pts.len() && fits(pts, i, j + 1, tol) {
            j += 1;
        }
        out.push(pts[j]);
        i = j;
    }
    out
}

fn fits(pts: &[V3], i: usize, j: usize, tol: f64) -> bool {
    let (a, b) = (pts[i], pts[j]);
    let l2 = (b.x - a.x).powi(2) + (b.y - a.y).powi(2);
    if l2 <= 0.0 {
        return false;
    }
    pts[i + 1..j].iter().all(|p| {
        let t = ((p.x - a.x) * (b.x - a.x) + (p.y - a.y) * (b.y - a.y)) / l2;
        let above = a.z + (b.z - a.z) * t - p.z;
        (-1e-12..=tol).contains(&above)
    })
}

/// Plans a raster finish of `mesh` with a drop-cutter: rows at the step-over in the
/// chosen direction over the mesh's plan view (or `area`), in the mesh's own frame.
pub fn finish3d(mesh: &Mesh, p: &Finish3dParams) -> Result<Toolpath, MeshError> {
    p.check()?;
    let dc = DropCutter::new(mesh, p.cutter)?;
    let (lo, hi) = mesh.bounds().ok_or_else(|| MeshError::Empty {
        name: mesh.name.clone(),
    })?;
    let area = p.area.unwrap_or([lo.x, lo.y, hi.x, hi.y]);
    if !(area[0] <= area[2] && area[1] <= area[3]) || area.iter().any(|v| !v.is_finite()) {
        return Err(MeshError::BadParam(format!(
            "the finishing area {area:?} is not [x_min, y_min, x_max, y_max]"
        )));
    }
    let floor = p.floor.unwrap_or(lo.z);
    let top = p.stock_top.unwrap_or(hi.z);
    let safe = top.max(hi.z) + p.safe_z;
    let step = p.stepover.mm(p.cutter.diameter);
    let rows = raster_rows(area, p.angle, step, p.zigzag);
    let tol = p.tolerance;
    let cl_rows: Vec<Vec<V3>> = rows
        .par_iter()
        .map(|&[a, b]| fit_row(&sample_line(&dc, a, b, floor, tol), tol))
        .collect();

    let mut tp = Toolpath::new("finish3d");
    tp.tool = Some(tool_of(&p.cutter, p.tool_number));
    tp.source = mesh.name.clone();
    // the drop-cutter needs no solid: a mesh's defects are said, not refused
    if let Some(d) = mesh.report().defects() {
        tp.warnings.push(format!("{} is {d}", mesh.name));
    }
    tp.push(Move::Comment {
        text: format!(
            "finish3d: {} cutter, step-over {step} mm at {}°, tolerance {tol} mm",
            describe(&p.cutter),
            p.angle
        ),
    });
    if p.spindle_rpm > 0.0 {
        tp.push(Move::Spindle { rpm: p.spindle_rpm });
    }
    let mut at: Option<V3> = None;
    for row in cl_rows.iter().filter(|r| !r.is_empty()) {
        let start = row[0];
        let linked = match at {
            Some(here)
                if p.zigzag
                    && ((here.x - start.x).powi(2) + (here.y - start.y).powi(2)).sqrt()
                        <= 2.0 * step + 1e-9 =>
            {
                // cut across to the next row along the drop-cutter surface
                let link = fit_row(
                    &sample_line(&dc, (here.x, here.y), (start.x, start.y), floor, tol),
                    tol,
                );
                for q in link.iter().skip(1) {
                    tp.push(Move::Linear {
                        to: q.p3(),
                        feed: p.feed,
                    });
                }
                true
            }
            _ => false,
        };
        if !linked {
            if let Some(here) = at {
                tp.push(Move::Rapid {
                    to: V3::new(here.x, here.y, safe).p3(),
                });
            }
            tp.push(Move::Rapid {
                to: V3::new(start.x, start.y, safe).p3(),
            });
            tp.push(Move::Linear {
                to: start.p3(),
                feed: p.plunge_feed,
            });
        }
        for q in row.iter().skip(1) {
            tp.push(Move::Linear {
                to: q.p3(),
                feed: p.feed,
            });
        }
        at = row.last().copied();
    }
    if let Some(here) = at {
        tp.push(Move::Rapid {
            to: V3::new(here.x, here.y, safe).p3(),
        });
    }
    if p.spindle_rpm > 0.0 {
        tp.push(Move::Spindle { rpm: 0.0 });
    }
    Ok(tp)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_cover_the_area_at_the_step_over() {
        let rows = raster_rows([0.0, 0.0, 10.0, 4.0], 0.0, 1.0, true);
        assert_eq!(rows.len(), 5);
        assert_eq!(rows[0], [(0.0, 0.0), (10.0, 0.0)]);
        assert_eq!(rows[1], [(10.0, 1.0), (0.0, 1.0)]);
        let diag = raster_rows([0.0, 0.0, 10.0, 10.0], 45.0, 0.5, false);
        for r in &diag {
            for (x, y) in r {
                assert!((-1e-9..=10.0 + 1e-9).contains(x) && (-1e-9..=10.0 + 1e-9).contains(y));
            }
        }
    }

    #[test]
    fn fitting_keeps_hills_and_drops_flats() {
        let pts: Vec<V3> = (0..=20)
            .map(|i| {
                let x = i as f64;
                V3::new(
                    x,
                    0.0,
                    if x > 8.0 && x < 12.0 {
                        1.0 - (x - 10.0).abs() * 0.4
                    } else {
                        0.0
                    },
                )
            })
            .collect();
        let fit = fit_row(&pts, 0.01);
        assert!(fit.len() < pts.len() && fit.len() >= 5, "{fit:?}");
        // no kept chord lies below a dropped point
        for w in fit.windows(2) {
            for p in &pts {
                if p.x > w[0].x && p.x < w[1].x {
                    let t = (p.x - w[0].x) / (w[1].x - w[0].x);
                    assert!(w[0].z + (w[1].z - w[0].z) * t >= p.z - 1e-12);
                }
            }
        }
    }
}
