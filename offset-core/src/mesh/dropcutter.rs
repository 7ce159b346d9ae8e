//! Drop-cutter: the lowest tool-tip height over a point at which a ball, flat or bull
//! cutter touches no triangle of a mesh (vertex, facet and edge tests), gouge-free by
//! construction.
//!
//! A cutter of radius R with a corner radius r (ball: r = R; flat: r = 0; bull: between)
//! has, at radial distance q from its axis, its lowest point h(q) above the tip: 0 on the
//! flat bottom (q ≤ R − r), r − √(r² − (q − R + r)²) on the corner. Over the point c, a
//! point p of the mesh within R of the axis asks for a tip no lower than p.z − h(|p − c|);
//! the drop-cutter height is the largest such demand over every triangle:
//! - vertex: each corner within R;
//! - facet: where the cutter's surface is parallel to the facet, i.e. the corner sphere
//!   whose centre lies R − r from the axis against the facet's uphill direction, r above
//!   the plane along its normal N; the contact point is that centre less r·N, and for a
//!   ball the tip follows r_L = r_c + R(N − u) (u the tool axis). It counts when the
//!   contact point lies inside the facet;
//! - edge: along an edge the demand z(t) − h(q(t)) is concave (a line less a convex
//!   function of a convex one), so its maximum over the part of the edge within R is the
//!   one stationary point: closed form for ball (a circle against a line in the edge's
//!   vertical plane) and flat (the rim circle meeting the edge), the root of the
//!   derivative by false position (Illinois) for a bull.
//!
//! Triangles come from a bounding-volume hierarchy split in plan view; a query visits
//! only boxes overlapping the cutter's square and reaching above the height found so far
//! (the highest first) and allocates nothing.

use super::bvh::Bvh;
use super::{Mesh, MeshError, V3};
use serde::{Deserialize, Serialize};
use std::str::FromStr;

/// The shape of a milling cutter's end.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CutterShape {
    /// Ball end: a hemisphere of the tool's radius.
    Ball,
    /// Flat end: a flat bottom to the full diameter, sharp corner.
    Flat,
    /// Bull nose: a flat bottom and a rounded corner of `corner_radius`.
    Bull,
}

impl FromStr for CutterShape {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "ball" => Ok(CutterShape::Ball),
            "flat" => Ok(CutterShape::Flat),
            "bull" | "bullnose" | "torus" => Ok(CutterShape::Bull),
            other => Err(format!("cutter \"{other}\" is not one of ball, flat, bull")),
        }
    }
}

/// A milling cutter, measured as a tool catalogue does (diameter, corner radius).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Cutter {
    pub shape: CutterShape,
    /// Diameter, mm.
    pub diameter: f64,
    /// Corner radius of a bull cutter, mm (ignored for ball and flat).
    #[serde(default)]
    pub corner_radius: f64,
}

impl Cutter {
    pub fn ball(diameter: f64) -> Cutter {
        Cutter {
            shape: CutterShape::Ball,
            diameter,
            corner_radius: 0.0,
        }
    }
    pub fn flat(diameter: f64) -> Cutter {
        Cutter {
            shape: CutterShape::Flat,
            diameter,
            corner_radius: 0.0,
        }
    }
    pub fn bull(diameter: f64, corner_radius: f64) -> Cutter {
        Cutter {
            shape: CutterShape::Bull,
            diameter,
            corner_radius,
        }
    }
    /// The tool radius R.
    pub fn radius(&self) -> f64 {
        self.diameter / 2.0
    }
    /// The corner radius r: R for a ball, 0 for a flat cutter.
    pub fn corner(&self) -> f64 {
        match self.shape {
            CutterShape::Ball => self.radius(),
            CutterShape::Flat => 0.0,
            CutterShape::Bull => self.corner_radius,
        }
    }
    /// Every value in range, or a sentence naming the first that is not.
    pub fn check(&self) -> Result<(), MeshError> {
        if !(self.diameter.is_finite() && self.diameter > 0.0) {
            return Err(MeshError::BadParam(format!(
                "the cutter diameter must be a positive number, got {}",
                self.diameter
            )));
        }
        if self.shape == CutterShape::Bull
            && !(self.corner_radius.is_finite()
                && self.corner_radius > 0.0
                && self.corner_radius <= self.radius())
        {
            return Err(MeshError::BadParam(format!(
                "a bull cutter's corner radius must be more than 0 and at most half its diameter ({} mm), got {}",
                self.radius(),
                self.corner_radius
            )));
        }
        Ok(())
    }
    /// How far above the tip the cutter's lowest point lies at radial distance `q` (≤ R).
    pub fn profile(&self, q: f64) -> f64 {
        let (rr, r) = (self.radius(), self.corner());
        let flat = rr - r;
        if q <= flat {
            0.0
        } else {
            let u = (q - flat).min(r);
            r - (r * r - u * u).max(0.0).sqrt()
        }
    }
}

/// A triangle ready for queries: corners, the upward unit normal and the highest Z.
#[derive(Clone, Copy, Debug)]
struct Tri {
    p: [V3; 3],
    n: V3,
    zmax: f64,
    /// plan-view box: x_min, y_min, x_max, y_max
    b: [f64; 4],
}

/// Where the cutter over a point touches the mesh.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Contact {
    /// The tool tip (the cutter location, CL).
    pub tip: V3,
    /// The contact point on the mesh (CC); None where nothing is under the cutter.
    pub cc: Option<V3>,
}

/// A mesh prepared for drop-cutter queries with one cutter.
#[derive(Clone, Debug)]
pub struct DropCutter {
    cutter: Cutter,
    r: f64,
    rc: f64,
    flat_r: f64,
    tris: Vec<Tri>,
    bvh: Bvh,
    /// The mesh's lowest Z: the height where nothing is under the cutter.
    pub floor: f64,
}

impl DropCutter {
    /// Prepares `mesh` for `cutter` (checks both).
    pub fn new(mesh: &Mesh, cutter: Cutter) -> Result<DropCutter, MeshError> {
        cutter.check()?;
        mesh.check_finite()?;
        let tris: Vec<[V3; 3]> = mesh.triangles().collect();
        let bvh = Bvh::new(&tris, true);
        let tris: Vec<Tri> = tris
            .iter()
            .map(|&p| {
                let n = (p[1] - p[0]).cross(p[2] - p[0]).unit();
                Tri {
                    p,
                    n: if n.z < 0.0 { -n } else { n },
                    zmax: p[0].z.max(p[1].z).max(p[2].z),
                    b: [
                        p[0].x.min(p[1].x).min(p[2].x),
                        p[0].y.min(p[1].y).min(p[2].y),
                        p[0].x.max(p[1].x).max(p[2].x),
                        p[0].y.max(p[1].y).max(p[2].y),
                    ],
                }
            })
            .collect();
        let floor = mesh.bounds().map(|(lo, _)| lo.z).unwrap_or(0.0);
        Ok(DropCutter {
            cutter,
            r: cutter.radius(),
            rc: cutter.corner(),
            flat_r: cutter.radius() - cutter.corner(),
            tris,
            bvh,
            floor,
        })
    }

    pub fn cutter(&self) -> Cutter {
        self.cutter
    }

    /// The lowest tip height over (x, y) touching no triangle, and no lower than `min_z`.
    pub fn drop(&self, x: f64, y: f64, min_z: f64) -> f64 {
        self.drop_contact(x, y, min_z).tip.z
    }

    /// The drop-cutter height over (x, y) (no lower than `min_z`) and the contact point.
    pub fn drop_contact(&self, x: f64, y: f64, min_z: f64) -> Contact {
        let mut best = min_z;
        let mut cc = None;
        let r = self.r;
        self.bvh
            .visit_xy_above(x - r, y - r, x + r, y + r, &mut best, |t, best| {
                let tri = &self.tris[t];
                if tri.zmax <= *best {
                    return;
                }
                // the triangle's plan-view box beyond the cutter's reach
                let dx = (tri.b[0] - x).max(0.0).max(x - tri.b[2]);
                let dy = (tri.b[1] - y).max(0.0).max(y - tri.b[3]);
                if dx * dx + dy * dy > r * r {
                    return;
                }
                if let Some((z, c)) = self.triangle(tri, x, y, *best) {
                    *best = z;
                    cc = Some(c);
                }
            });
        Contact {
            tip: V3::new(x, y, best),
            cc,
        }
    }

    /// The highest demand of one triangle over (x, y) above `above`, with its contact point.
    fn triangle(&self, t: &Tri, x: f64, y: f64, above: f64) -> Option<(f64, V3)> {
        let mut best: Option<(f64, V3)> = None;
        let mut take = |z: f64, c: V3| {
            if z > above && best.is_none_or(|(b, _)| z > b) {
                best = Some((z, c));
            }
        };
        let r2 = self.r * self.r;
        for &p in &t.p {
            let q2 = (p.x - x).powi(2) + (p.y - y).powi(2);
            if q2 <= r2 {
                take(p.z - self.cutter.profile(q2.sqrt()), p);
            }
        }
        if let Some((z, c)) = self.facet(t, x, y) {
            take(z, c);
        }
        for k in 0..3 {
            if let Some((z, c)) = self.edge(t.p[k], t.p[(k + 1) % 3], x, y) {
                take(z, c);
            }
        }
        best
    }

    /// Facet test: the tip where the cutter touches the facet's plane, if the contact
    /// point lies in the facet.
    fn facet(&self, t: &Tri, x: f64, y: f64) -> Option<(f64, V3)> {
        let n = t.n;
        if n.z < 1e-12 {
            return None;
        }
        let nxy = (n.x * n.x + n.y * n.y).sqrt();
        let (ux, uy) = if nxy > 1e-15 {
            (-n.x / nxy, -n.y / nxy)
        } else {
            (0.0, 0.0)
        };
        // the corner sphere's centre: R − r from the axis uphill, r above the plane
        let sx = x + self.flat_r * ux;
        let sy = y + self.flat_r * uy;
        let p0 = t.p[0];
        let sz = p0.z + (self.rc - n.x * (sx - p0.x) - n.y * (sy - p0.y)) / n.z;
        let cc = V3::new(sx, sy, sz) - n * self.rc;
        if !inside_xy(&t.p, cc.x, cc.y) {
            return None;
        }
        Some((sz - self.rc, cc))
    }

    /// Edge test: the highest demand along the inside of edge a→b (its ends are the
    /// vertex test's).
    fn edge(&self, a: V3, b: V3, x: f64, y: f64) -> Option<(f64, V3)> {
        let (lx, ly, lz) = (b.x - a.x, b.y - a.y, b.z - a.z);
        let l2 = lx * lx + ly * ly;
        if l2 < 1e-24 {
            return None; // vertical: its top is a vertex
        }
        let l = l2.sqrt();
        let (ex, ey) = (lx / l, ly / l);
        let (cx, cy) = (x - a.x, y - a.y);
        let t0 = cx * ex + cy * ey; // along the edge, mm from a
        let d = cx * ey - cy * ex; // across it
        let d2 = d * d;
        let r = self.r;
        if d2 >= r * r {
            return None;
        }
        let m = lz / l; // slope
        let at = |t: f64| V3::new(a.x + ex * t, a.y + ey * t, a.z + m * t);
        match self.cutter.shape {
            CutterShape::Ball => {
                let s = (r * r - d2).sqrt();
                let k = (1.0 + m * m).sqrt();
                let tc = t0 + s * m / k;
                if !(0.0..=l).contains(&tc) {
                    return None;
                }
                let zc = a.z + m * t0 + s * k;
                Some((zc - r, at(tc)))
            }
            CutterShape::Flat => {
                let w = (r * r - d2).sqrt();
                // the higher end of the chord inside the rim
                let tc = if m >= 0.0 { t0 + w } else { t0 - w };
                if !(0.0..=l).contains(&tc) {
                    return None;
                }
                let p = at(tc);
                Some((p.z, p))
            }
            CutterShape::Bull => {
                let w = (r * r - d2).sqrt();
                let (ta, tb) = ((t0 - w).max(0.0), (t0 + w).min(l));
                if ta > tb {
                    return None;
                }
                let demand = |t: f64| {
                    let q = (d2 + (t - t0) * (t - t0)).sqrt();
                    a.z + m * t - self.cutter.profile(q)
                };
                // the derivative's sign: m − h'(q)·(t − t0)/q, decreasing in t
                let flat = self.flat_r;
                let rc = self.rc;
                let slope = |t: f64| {
                    let q = (d2 + (t - t0) * (t - t0)).sqrt();
                    let u = q - flat;
                    if u <= 0.0 {
                        return m;
                    }
                    let rest = rc * rc - u * u;
                    if rest <= 0.0 {
                        return if t > t0 {
                            f64::NEG_INFINITY
                        } else {
                            f64::INFINITY
                        };
                    }
                    m - u / rest.sqrt() * (t - t0) / q
                };
                let tc = if slope(ta) <= 0.0 {
                    ta
                } else if slope(tb) >= 0.0 {
                    tb
                } else {
                    // the root of the decreasing slope: false position (Illinois) while
                    // both ends are finite, halving otherwise
                    let (mut lo, mut hi) = (ta, tb);
                    let (mut glo, mut ghi) = (slope(lo), slope(hi));
                    let mut side = 0i8;
                    let eps = 1e-13 * (1.0 + l);
                    for _ in 0..100 {
                        if hi - lo <= eps {
                            break;
                        }
                        let mut mid = if glo.is_finite() && ghi.is_finite() {
                            lo + (hi - lo) * glo / (glo - ghi)
                        } else {
                            0.5 * (lo + hi)
                        };
                        if !(mid > lo && mid < hi) {
                            mid = 0.5 * (lo + hi);
                        }
                        let g = slope(mid);
                        if g == 0.0 {
                            lo = mid;
                            hi = mid;
                            break;
                        }
                        if g > 0.0 {
                            lo = mid;
                            glo = g;
                            if side == 1 {
                                ghi *= 0.5;
                            }
                            side = 1;
                        } else {
                            hi = mid;
                            ghi = g;
                            if side == -1 {
                                glo *= 0.5;
                            }
                            side = -1;
                        }
                    }
                    0.5 * (lo + hi)
                };
                if tc <= 0.0 || tc >= l {
                    return None; // an end: the vertex test's
                }
                Some((demand(tc), at(tc)))
            }
        }
    }

    /// Drop-cutter heights over many points at once, in parallel (rayon); each no lower
    /// than `min_z`.
    pub fn drop_many(&self, xy: &[(f64, f64)], min_z: f64) -> Vec<f64> {
        use rayon::prelude::*;
        xy.par_iter()
            .with_min_len(64)
            .map(|&(x, y)| self.drop(x, y, min_z))
            .collect()
    }
}

/// Whether (x, y) lies in the plan view of triangle `p` (edges included, a hair of slack).
fn inside_xy(p: &[V3; 3], x: f64, y: f64) -> bool {
    let e = |a: V3, b: V3| (b.x - a.x) * (y - a.y) - (b.y - a.y) * (x - a.x);
    let (w0, w1, w2) = (e(p[0], p[1]), e(p[1], p[2]), e(p[2], p[0]));
    let area = w0 + w1 + w2;
    let slack = -1e-12 * area.abs();
    if area >= 0.0 {
        w0 >= slack && w1 >= slack && w2 >= slack
    } else {
        w0 <= -slack && w1 <= -slack && w2 <= -slack
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn one(t: [V3; 3]) -> Mesh {
        Mesh::new("one", t.to_vec(), vec![[0, 1, 2]])
    }

    #[test]
    fn tilted_facet_matches_the_plane_formulas() {
        // z = 0.5 y; over (3, 3) the plane is at 1.5; the same case OpenCAMLib gives
        // 1.618034 (ball d2), 2.0 (flat d2), 1.885410 (bull d2 r0.3)
        let m = one([
            V3::new(0.0, 0.0, 0.0),
            V3::new(10.0, 0.0, 0.0),
            V3::new(0.0, 10.0, 5.0),
        ]);
        for (c, want) in [
            (Cutter::ball(2.0), 1.5 + 1.25f64.sqrt() - 1.0),
            (Cutter::flat(2.0), 2.0),
            (
                Cutter::bull(2.0, 0.3),
                1.5 + 0.35 + 0.3 * (1.25f64.sqrt() - 1.0),
            ),
        ] {
            let dc = DropCutter::new(&m, c).unwrap();
            let z = dc.drop(3.0, 3.0, -100.0);
            assert!((z - want).abs() < 1e-12, "{c:?}: {z} vs {want}");
        }
    }

    #[test]
    fn nothing_under_the_cutter_leaves_the_floor() {
        let m = one([
            V3::new(0.0, 0.0, 0.0),
            V3::new(10.0, 0.0, 0.0),
            V3::new(0.0, 10.0, 5.0),
        ]);
        let dc = DropCutter::new(&m, Cutter::ball(2.0)).unwrap();
        assert_eq!(dc.drop(30.0, 3.0, -100.0), -100.0);
    }

    #[test]
    fn a_ridge_edge_is_met_by_the_edge_test() {
        // two facets meeting in a horizontal ridge along X at z = 1, falling away at 45°
        let m = Mesh::new(
            "ridge",
            vec![
                V3::new(0.0, 0.0, 1.0),
                V3::new(10.0, 0.0, 1.0),
                V3::new(0.0, 5.0, -4.0),
                V3::new(10.0, 5.0, -4.0),
                V3::new(0.0, -5.0, -4.0),
                V3::new(10.0, -5.0, -4.0),
            ],
            vec![[0, 1, 3], [0, 3, 2], [0, 4, 5], [0, 5, 1]],
        );
        // a ball straight over the ridge touches the edge: tip at the ridge
        for (c, dy, want) in [
            (Cutter::ball(4.0), 0.0, 1.0),
            (Cutter::flat(4.0), 0.0, 1.0),
            (Cutter::bull(4.0, 1.0), 0.0, 1.0),
            // 1.5 off the ridge: ball centre 2 from the ridge line: (1.5, zc): zc = sqrt(4 - 2.25)
            // 1 off the ridge a ball's centre is 2 from the ridge line (the facet's contact
            // would fall across the ridge): zc = 1 + sqrt(4 - 1)
            (Cutter::ball(4.0), 1.0, 1.0 + 3.0f64.sqrt() - 2.0),
            (Cutter::flat(4.0), 1.5, 1.0),
            // a bull's corner (flat to 1, r = 1) meets the ridge 1.5 off the axis
            (Cutter::bull(4.0, 1.0), 1.5, 0.75f64.sqrt()),
        ] {
            let dc = DropCutter::new(&m, c).unwrap();
            let z = dc.drop(5.0, dy, -100.0);
            assert!((z - want).abs() < 1e-9, "{c:?} at dy {dy}: {z} vs {want}");
        }
    }
}
