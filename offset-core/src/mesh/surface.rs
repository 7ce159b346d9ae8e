//! Surfaces from measured points: a grid of points (CSV `x,y,z`, rows of equal length, as
//! a CMM or a probing run writes them) fitted with a bicubic surface through every point,
//! and tessellated within a tolerance into a mesh.
//!
//! The fit is the tensor-product cubic spline with not-a-knot ends (uniform parameters,
//! one per row and column of the grid), written as one Ferguson patch per grid cell
//! (corner points, tangents and twists), so it is C2 across patches and reproduces any
//! bicubic exactly. The tessellation splits each patch from a bound on its second
//! derivatives (from its Bézier control points): a triangle over parameter steps hu, hv
//! strays at most ½(hu²·|Puu| + 2·hu·hv·|Puv| + hv²·|Pvv|) from the patch, and the steps
//! are chosen to keep that within the tolerance; columns and rows of patches share their
//! steps, so the mesh has no cracks.

use super::{Mesh, MeshError, V3};

/// The most points a grid may hold (a bigger one is refused by name).
pub const MAX_GRID_POINTS: usize = 1_000_000;

/// A grid of measured points, row by row (each row the same length).
#[derive(Clone, Debug, PartialEq)]
pub struct PointGrid {
    pub rows: usize,
    pub cols: usize,
    /// Row-major: point (row r, column c) at `r * cols + c`.
    pub points: Vec<V3>,
}

impl PointGrid {
    pub fn at(&self, r: usize, c: usize) -> V3 {
        self.points[r * self.cols + c]
    }
}

/// Reads a point grid from CSV text: `x,y,z` per line (commas, semicolons, tabs or spaces
/// between values; `#` starts a comment; a header line of names is skipped). Rows of the
/// grid are separated by blank lines, or each line holds a whole row (`x,y,z,x,y,z,…`), or
/// else a new row starts where the coordinate that stayed fixed along the first row
/// changes. Rows scanned back and forth are turned to run the same way. Ragged rows,
/// words where numbers belong, NaN or infinite values and grids with fewer than 2 rows or
/// columns are one error sentence naming the line.
pub fn read_point_grid(bytes: &[u8], name: &str) -> Result<PointGrid, MeshError> {
    let text = std::str::from_utf8(bytes).map_err(|e| MeshError::Csv {
        name: name.into(),
        line: 1 + bytes[..e.valid_up_to()]
            .iter()
            .filter(|&&b| b == b'\n')
            .count(),
        message: "is not text (UTF-8)".into(),
    })?;
    let csv_err = |line: usize, message: String| MeshError::Csv {
        name: name.into(),
        line,
        message,
    };
    // (line number, points) per row as the file groups them; None marks a blank line
    let mut lines: Vec<Option<(usize, Vec<V3>)>> = Vec::new();
    let mut seen_data = false;
    let mut total = 0usize;
    for (k, raw) in text.lines().enumerate() {
        let ln = k + 1;
        let body = raw.split('#').next().unwrap_or("").trim();
        if body.is_empty() {
            if raw.trim().is_empty() {
                lines.push(None);
            }
            continue;
        }
        let fields: Vec<&str> = body
            .split(|c: char| c == ',' || c == ';' || c.is_whitespace())
            .filter(|s| !s.is_empty())
            .collect();
        if fields.is_empty() {
            // only separators (",,,"): as good as a blank line
            lines.push(None);
            continue;
        }
        let nums: Result<Vec<f64>, _> = fields.iter().map(|f| f.parse::<f64>()).collect();
        let nums = match nums {
            Ok(v) => v,
            Err(_) if !seen_data => continue, // a header
            Err(_) => {
                let bad = fields.iter().find(|f| f.parse::<f64>().is_err()).unwrap();
                return Err(csv_err(ln, format!("\"{bad}\" is not a number")));
            }
        };
        seen_data = true;
        if let Some(i) = nums.iter().position(|v| !v.is_finite()) {
            return Err(csv_err(
                ln,
                format!("value {} is not a finite number", i + 1),
            ));
        }
        if nums.len() % 3 != 0 {
            return Err(csv_err(
                ln,
                format!(
                    "has {} values; a point is x,y,z (3 values a point)",
                    nums.len()
                ),
            ));
        }
        total += nums.len() / 3;
        if total > MAX_GRID_POINTS {
            return Err(csv_err(
                ln,
                format!("the grid has more than {MAX_GRID_POINTS} points (the budget)"),
            ));
        }
        let pts = nums.chunks(3).map(|c| V3::new(c[0], c[1], c[2])).collect();
        lines.push(Some((ln, pts)));
    }
    let data: Vec<&(usize, Vec<V3>)> = lines.iter().flatten().collect();
    if data.is_empty() {
        return Err(csv_err(1, "holds no points".into()));
    }
    let whole_rows = data.iter().any(|(_, p)| p.len() > 1);
    let mut rows: Vec<(usize, Vec<V3>)> = Vec::new();
    if whole_rows {
        rows = data.iter().map(|(l, p)| (*l, p.clone())).collect();
    } else {
        let blank_split = lines
            .iter()
            .skip_while(|l| l.is_none())
            .collect::<Vec<_>>()
            .windows(2)
            .any(|w| w[0].is_none() && w[1].is_some());
        if blank_split {
            let mut cur: Option<(usize, Vec<V3>)> = None;
            for l in &lines {
                match l {
                    None => {
                        if let Some(r) = cur.take() {
                            rows.push(r);
                        }
                    }
                    Some((ln, p)) => cur.get_or_insert((*ln, Vec::new())).1.push(p[0]),
                }
            }
            rows.extend(cur);
        } else {
            // rows where the fixed coordinate of the first row changes
            let pts: Vec<(usize, V3)> = data.iter().map(|(l, p)| (*l, p[0])).collect();
            if pts.len() < 2 {
                return Err(csv_err(
                    pts[0].0,
                    "a grid needs at least 2 rows and 2 columns".into(),
                ));
            }
            let (a, b) = (pts[0].1, pts[1].1);
            let along_x = (b.x - a.x).abs() >= (b.y - a.y).abs();
            let fixed = |p: V3| if along_x { p.y } else { p.x };
            let step = if along_x {
                (b.x - a.x).abs()
            } else {
                (b.y - a.y).abs()
            };
            let tol = (step * 1e-3).max(1e-9);
            for &(ln, p) in &pts {
                match rows.last_mut() {
                    Some((_, r)) if (fixed(r[0]) - fixed(p)).abs() <= tol => r.push(p),
                    _ => rows.push((ln, vec![p])),
                }
            }
        }
    }
    let cols = rows[0].1.len();
    for (k, (ln, r)) in rows.iter().enumerate() {
        if r.len() != cols {
            return Err(MeshError::Ragged {
                name: name.into(),
                row: k + 1,
                line: *ln,
                len: r.len(),
                expected: cols,
            });
        }
    }
    if rows.len() < 2 || cols < 2 {
        return Err(csv_err(
            rows[0].0,
            format!(
                "a grid needs at least 2 rows and 2 columns, this one has {} × {cols}",
                rows.len()
            ),
        ));
    }
    // rows scanned back and forth run the first row's way
    let dir0 = rows[0].1[cols - 1] - rows[0].1[0];
    let mut points = Vec::with_capacity(rows.len() * cols);
    for (_, r) in &mut rows {
        if (r[cols - 1] - r[0]).dot(dir0) < 0.0 {
            r.reverse();
        }
        points.extend_from_slice(r);
    }
    Ok(PointGrid {
        rows: rows.len(),
        cols,
        points,
    })
}

/// A bicubic surface through every point of a grid: one Ferguson patch per cell, the
/// parameters u = column (0 … cols − 1) and v = row (0 … rows − 1).
#[derive(Clone, Debug, PartialEq)]
pub struct BicubicSurface {
    pub rows: usize,
    pub cols: usize,
    p: Vec<V3>,
    pu: Vec<V3>,
    pv: Vec<V3>,
    puv: Vec<V3>,
}

impl BicubicSurface {
    /// The spline surface through every point of `g`.
    pub fn fit(g: &PointGrid) -> BicubicSurface {
        let (rows, cols) = (g.rows, g.cols);
        let mut pu = vec![V3::ZERO; rows * cols];
        let mut pv = vec![V3::ZERO; rows * cols];
        let mut puv = vec![V3::ZERO; rows * cols];
        for r in 0..rows {
            let row: Vec<V3> = (0..cols).map(|c| g.at(r, c)).collect();
            for (c, d) in spline_slopes(&row).into_iter().enumerate() {
                pu[r * cols + c] = d;
            }
        }
        for c in 0..cols {
            let col: Vec<V3> = (0..rows).map(|r| g.at(r, c)).collect();
            for (r, d) in spline_slopes(&col).into_iter().enumerate() {
                pv[r * cols + c] = d;
            }
            let colu: Vec<V3> = (0..rows).map(|r| pu[r * cols + c]).collect();
            for (r, d) in spline_slopes(&colu).into_iter().enumerate() {
                puv[r * cols + c] = d;
            }
        }
        BicubicSurface {
            rows,
            cols,
            p: g.points.clone(),
            pu,
            pv,
            puv,
        }
    }

    /// The patch of cell (row j, column i) as 4 × 4 Bézier control points `b[k][l]`
    /// (k along u, l along v).
    pub fn bezier(&self, j: usize, i: usize) -> [[V3; 4]; 4] {
        let id = |r: usize, c: usize| r * self.cols + c;
        let corner = |a: usize, b: usize| id(j + b, i + a);
        // Hermite data per corner (a along u, b along v)
        let mut out = [[V3::ZERO; 4]; 4];
        // along u for each of the two v-ends: values and v-derivatives as Bézier in u
        let to_bez = |p0: V3, p1: V3, d0: V3, d1: V3| [p0, p0 + d0 / 3.0, p1 - d1 / 3.0, p1];
        for b in 0..2 {
            let pos = to_bez(
                self.p[corner(0, b)],
                self.p[corner(1, b)],
                self.pu[corner(0, b)],
                self.pu[corner(1, b)],
            );
            let dv = to_bez(
                self.pv[corner(0, b)],
                self.pv[corner(1, b)],
                self.puv[corner(0, b)],
                self.puv[corner(1, b)],
            );
            for k in 0..4 {
                if b == 0 {
                    out[k][0] = pos[k];
                    out[k][1] = pos[k] + dv[k] / 3.0;
                } else {
                    out[k][3] = pos[k];
                    out[k][2] = pos[k] - dv[k] / 3.0;
                }
            }
        }
        out
    }

    /// The point at parameters (u, v), u in [0, cols − 1], v in [0, rows − 1] (clamped).
    pub fn eval(&self, u: f64, v: f64) -> V3 {
        let u = u.clamp(0.0, (self.cols - 1) as f64);
        let v = v.clamp(0.0, (self.rows - 1) as f64);
        let i = (u.floor() as usize).min(self.cols - 2);
        let j = (v.floor() as usize).min(self.rows - 2);
        let b = self.bezier(j, i);
        let (s, t) = (u - i as f64, v - j as f64);
        let bs = bernstein(s);
        let bt = bernstein(t);
        let mut q = V3::ZERO;
        for (k, row) in b.iter().enumerate() {
            for (l, &c) in row.iter().enumerate() {
                q += c * (bs[k] * bt[l]);
            }
        }
        q
    }

    /// Bounds on |Puu|, |Puv|, |Pvv| over the cell (row j, column i), from its control
    /// points.
    #[allow(clippy::needless_range_loop)] // index arithmetic reads as the formulas
    fn second_derivative_bounds(&self, j: usize, i: usize) -> (f64, f64, f64) {
        let b = self.bezier(j, i);
        let (mut uu, mut uv, mut vv) = (0.0f64, 0.0f64, 0.0f64);
        for l in 0..4 {
            for k in 0..2 {
                uu = uu.max((b[k + 2][l] - b[k + 1][l] * 2.0 + b[k][l]).len() * 6.0);
                vv = vv.max((b[l][k + 2] - b[l][k + 1] * 2.0 + b[l][k]).len() * 6.0);
            }
        }
        for k in 0..3 {
            for l in 0..3 {
                uv = uv.max((b[k + 1][l + 1] - b[k + 1][l] - b[k][l + 1] + b[k][l]).len() * 9.0);
            }
        }
        (uu, uv, vv)
    }

    /// Parameter steps per column and per row of cells that keep every triangle within
    /// `tol` of the surface.
    #[allow(clippy::needless_range_loop)] // cells indexed by (row, column)
    fn steps(&self, tol: f64) -> (Vec<usize>, Vec<usize>) {
        let mut nu = vec![1usize; self.cols - 1];
        let mut nv = vec![1usize; self.rows - 1];
        for j in 0..self.rows - 1 {
            for i in 0..self.cols - 1 {
                let (uu, uv, vv) = self.second_derivative_bounds(j, i);
                let mut a = ((1.5 * uu / tol).sqrt().ceil() as usize).max(1);
                let mut b = ((1.5 * vv / tol).sqrt().ceil() as usize).max(1);
                while 3.0 * uv / (a * b) as f64 > tol && a.max(b) < 100_000 {
                    if a <= b {
                        a += 1;
                    } else {
                        b += 1;
                    }
                }
                nu[i] = nu[i].max(a);
                nv[j] = nv[j].max(b);
            }
        }
        (nu, nv)
    }

    /// The parameters of the tessellation's columns and rows at tolerance `tol`.
    pub fn tessellation_params(&self, tol: f64) -> (Vec<f64>, Vec<f64>) {
        let (nu, nv) = self.steps(tol);
        let line = |n: &[usize]| {
            let mut t = vec![0.0];
            for (i, &k) in n.iter().enumerate() {
                for s in 1..=k {
                    t.push(i as f64 + s as f64 / k as f64);
                }
            }
            t
        };
        (line(&nu), line(&nv))
    }

    /// The surface as an open mesh whose triangles lie within `tol` of it (two per step
    /// cell, facing the side the grid's rows and columns turn counter-clockwise about).
    pub fn tessellate(&self, name: &str, tol: f64) -> Result<Mesh, MeshError> {
        if !(tol.is_finite() && tol > 0.0) {
            return Err(MeshError::BadParam(format!(
                "the tessellation tolerance must be a positive number, got {tol}"
            )));
        }
        let (us, vs) = self.tessellation_params(tol);
        let faces = 2 * (us.len() - 1) * (vs.len() - 1);
        if faces > super::MAX_FACES {
            return Err(MeshError::TooBig {
                name: name.into(),
                faces,
                budget: super::MAX_FACES,
            });
        }
        let mut vertices = Vec::with_capacity(us.len() * vs.len());
        for &v in &vs {
            for &u in &us {
                vertices.push(self.eval(u, v));
            }
        }
        let w = us.len();
        let id = |i: usize, j: usize| (j * w + i) as u32;
        let mut fs = Vec::with_capacity(faces);
        for j in 0..vs.len() - 1 {
            for i in 0..w - 1 {
                fs.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                fs.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        let mut m = Mesh::new(name, vertices, fs);
        // face up where the surface is a height field over its grid
        if m.face_area2(0).z + m.face_area2(m.faces.len() - 1).z < 0.0 {
            m = m.flipped();
        }
        m.check_finite()?;
        Ok(m)
    }

    /// The surface closed into a solid for roughing: its tessellation, walls straight
    /// down from its rim to `base` and a flat bottom there (`base` must lie below the
    /// surface; the rim's plan view must be star-shaped about its centroid, as a grid's is).
    pub fn solid(&self, name: &str, tol: f64, base: f64) -> Result<Mesh, MeshError> {
        let mut m = self.tessellate(name, tol)?;
        let (lo, _) = m.bounds().expect("a tessellation has faces");
        if base.partial_cmp(&lo.z) != Some(std::cmp::Ordering::Less) {
            return Err(MeshError::BadParam(format!(
                "the base Z {base} of the solid must lie below the surface's lowest point, Z {}",
                lo.z
            )));
        }
        let (us, vs) = self.tessellation_params(tol);
        let (w, h) = (us.len(), vs.len());
        let id = |i: usize, j: usize| (j * w + i) as u32;
        let mut rim = Vec::new();
        for i in 0..w - 1 {
            rim.push(id(i, 0));
        }
        for j in 0..h - 1 {
            rim.push(id(w - 1, j));
        }
        for i in (1..w).rev() {
            rim.push(id(i, h - 1));
        }
        for j in (1..h).rev() {
            rim.push(id(0, j));
        }
        // counter-clockwise seen from above
        let area: f64 = (0..rim.len())
            .map(|k| {
                let (a, b) = (
                    m.vertices[rim[k] as usize],
                    m.vertices[rim[(k + 1) % rim.len()] as usize],
                );
                a.x * b.y - b.x * a.y
            })
            .sum();
        if area < 0.0 {
            rim.reverse();
        }
        super::shapes::close_down(&mut m, &rim, base);
        Ok(m)
    }
}

/// Reads a CSV point grid and fits it: the surface and its tessellation within `tol`.
pub fn mesh_from_points(
    bytes: &[u8],
    name: &str,
    tol: f64,
) -> Result<(BicubicSurface, Mesh), MeshError> {
    let g = read_point_grid(bytes, name)?;
    let s = BicubicSurface::fit(&g);
    let m = s.tessellate(name, tol)?;
    Ok((s, m))
}

fn bernstein(t: f64) -> [f64; 4] {
    let s = 1.0 - t;
    [s * s * s, 3.0 * s * s * t, 3.0 * s * t * t, t * t * t]
}

/// Slopes (derivatives per unit parameter) of the not-a-knot cubic spline through `y` at
/// parameters 0, 1, 2, …; a parabola through three points, a line through two.
fn spline_slopes(y: &[V3]) -> Vec<V3> {
    let n = y.len();
    match n {
        0 => return Vec::new(),
        1 => return vec![V3::ZERO],
        2 => return vec![y[1] - y[0]; 2],
        3 => {
            return vec![
                (y[1] * 4.0 - y[0] * 3.0 - y[2]) / 2.0,
                (y[2] - y[0]) / 2.0,
                (y[0] - y[1] * 4.0 + y[2] * 3.0) / 2.0,
            ]
        }
        _ => {}
    }
    // interior: m[i-1] + 4 m[i] + m[i+1] = 3 (y[i+1] - y[i-1]); not-a-knot ends (the
    // third derivative continuous at the second and the last but one point):
    // m0 = m2 + 2(2y1 - y0 - y2) and m[n-1] = m[n-3] - 2(2y[n-2] - y[n-1] - y[n-3])
    let c0 = (y[1] * 2.0 - y[0] - y[2]) * 2.0;
    let c1 = (y[n - 2] * 2.0 - y[n - 1] - y[n - 3]) * 2.0;
    let k = n - 2; // unknowns m1 … m[n-2]
    let mut sub = vec![1.0; k];
    let mut diag = vec![4.0; k];
    let mut sup = vec![1.0; k];
    let mut rhs: Vec<V3> = (1..n - 1).map(|i| (y[i + 1] - y[i - 1]) * 3.0).collect();
    // first row: (m2 + c0) + 4 m1 + m2
    sup[0] = 2.0;
    rhs[0] = rhs[0] - c0; // (V3 has no -=)
                          // last row: m[n-3] + 4 m[n-2] + (m[n-3] - c1)
    sub[k - 1] = 2.0;
    rhs[k - 1] += c1;
    // Thomas algorithm
    for i in 1..k {
        let w = sub[i] / diag[i - 1];
        diag[i] -= w * sup[i - 1];
        rhs[i] = rhs[i] - rhs[i - 1] * w;
    }
    let mut m = vec![V3::ZERO; n];
    m[k] = rhs[k - 1] / diag[k - 1];
    for i in (0..k - 1).rev() {
        m[i + 1] = (rhs[i] - m[i + 2] * sup[i]) / diag[i];
    }
    m[0] = m[2] + c0;
    m[n - 1] = m[n - 3] - c1;
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_spline_reproduces_a_cubic() {
        let f = |t: f64| V3::new(t, 2.0 * t * t * t - t * t + 0.5, -t * t + 3.0);
        let df = |t: f64| V3::new(1.0, 6.0 * t * t - 2.0 * t, -2.0 * t);
        for n in [4, 5, 9] {
            let y: Vec<V3> = (0..n).map(|i| f(i as f64)).collect();
            for (i, m) in spline_slopes(&y).iter().enumerate() {
                assert!(m.dist(df(i as f64)) < 1e-9, "n {n}, slope {i}: {m:?}");
            }
        }
    }

    #[test]
    fn rows_come_from_blank_lines_whole_lines_or_the_scan() {
        let blank = b"x,y,z\n0,0,1\n1,0,1\n2,0,1\n\n0,1,2\n1,1,2\n2,1,2\n";
        let whole = b"0,0,1, 1,0,1, 2,0,1\n0,1,2, 1,1,2, 2,1,2\n";
        // scanned back and forth, one point a line
        let scan = b"0 0 1\n1 0 1\n2 0 1\n2 1 2\n1 1 2\n0 1 2\n";
        for (case, bytes) in [
            ("blank", &blank[..]),
            ("whole", &whole[..]),
            ("scan", &scan[..]),
        ] {
            let g = read_point_grid(bytes, case).unwrap();
            assert_eq!((g.rows, g.cols), (2, 3), "{case}");
            assert_eq!(g.at(1, 0), V3::new(0.0, 1.0, 2.0), "{case}");
        }
    }
}
