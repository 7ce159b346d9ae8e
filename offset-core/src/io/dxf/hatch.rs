//! DXF HATCH boundaries: a hatch's boundary paths read as closed loops (in the hatch's own
//! units), and its style's choice of which of them bound the filled area.
//!
//! A boundary path is either a polyline path (vertices with bulges) or an edge path
//! (lines, circular arcs, elliptic arcs and splines, joined end to end here). The groups
//! are read in the order the DXF reference gives them, following the counts only where
//! a leading group code marks each item (92 a path, 72 an edge), so a wrong count can
//! neither run past the entity nor make the reader allocate by it. Loops that do not
//! close are skipped with a warning; groups that make no sense are errors naming the
//! hatch (type, handle, line, layer) and the boundary path.

use super::{parse_num, Entity, Group};
use crate::flatten;
use crate::geom::{Point, Polyline, Vertex};
use crate::io::chain::chain;
use crate::io::ImportError;

/// One boundary loop of a hatch, in the hatch's units.
pub(super) struct Loop {
    pub polyline: Polyline,
    /// Whether curves (elliptic arcs, splines) were flattened into it: it is then fitted
    /// within half the tolerance, as ELLIPSE and SPLINE are.
    pub flattened: bool,
}

/// A hatch's loops and its style (group 75: 0 normal, odd parity; 1 outer: the outermost
/// loops and the islands directly in them; 2 ignore: the outermost loops only).
pub(super) struct Hatch {
    pub loops: Vec<Loop>,
    pub style: i64,
}

/// Reads the boundary paths of HATCH `e` on `layer`; `ltol` is the tolerance in the
/// hatch's units (joining edges, flattening curves), `tol_mm` the same in mm for messages.
pub(super) fn read(
    e: &Entity,
    layer: &str,
    file: &str,
    ltol: f64,
    tol_mm: f64,
    warnings: &mut Vec<String>,
) -> Result<Hatch, ImportError> {
    let who = format!("{} on layer {layer}", e.handle());
    let Some(start) = e.groups.iter().position(|g| g.code == 91) else {
        warnings.push(format!("{who} has no boundary paths; skipped"));
        return Ok(Hatch {
            loops: Vec::new(),
            style: 0,
        });
    };
    let mut r = Reader {
        e,
        gs: e.groups,
        i: start + 1,
        file,
        who,
        path: 0,
    };
    let count = r.int_of(&e.groups[start])?;
    let mut loops = Vec::new();
    while r.peek() == Some(92) && (r.path as i64) < count.max(0) {
        let flags = r.need_int(92, "the boundary path's type")?;
        if flags & 2 != 0 {
            if let Some(l) = r.polyline_path()? {
                loops.push(l);
            } else {
                warnings.push(format!(
                    "{}: boundary path {} has fewer than two vertices; skipped",
                    r.who, r.path
                ));
            }
        } else {
            let pieces = r.edge_path(ltol, tol_mm)?;
            let flattened = pieces.iter().any(|(_, f)| *f);
            let pieces: Vec<Polyline> = pieces.into_iter().map(|(p, _)| p).collect();
            let mut ignored = Vec::new();
            let joined = chain(pieces, ltol, &mut ignored);
            for pl in joined {
                if pl.closed {
                    loops.push(Loop {
                        polyline: pl,
                        flattened,
                    });
                } else {
                    let (a, b) = (pl.vertices[0].pos(), pl.vertices[pl.len() - 1].pos());
                    warnings.push(format!(
                        "{}: boundary path {} is not closed (its edges end at ({:.4}, {:.4}) and ({:.4}, {:.4})); that part skipped",
                        r.who, r.path, a.x, a.y, b.x, b.y
                    ));
                }
            }
        }
        // the source boundary objects (97 count, 330 handles) end each path
        while matches!(r.peek(), Some(97 | 330)) {
            r.i += 1;
        }
        r.path += 1;
    }
    let style = r.gs[r.i..]
        .iter()
        .find(|g| g.code == 75)
        .map(|g| r.int_of(g))
        .transpose()?
        .unwrap_or(0);
    if !(0..=2).contains(&style) {
        warnings.push(format!(
            "{}: hatch style {style} is not one of 0, 1, 2; read as 0 (normal)",
            r.who
        ));
    }
    Ok(Hatch { loops, style })
}

/// Which of a hatch's placed loops bound its filled area under `style`: all (0), those
/// nested at most one deep among the hatch's own loops (1), the outermost (2).
pub(super) fn keep_by_style(loops: &[Polyline], style: i64) -> Vec<bool> {
    let max_depth = match style {
        1 => 1,
        2 => 0,
        _ => return vec![true; loops.len()],
    };
    let areas: Vec<f64> = loops.iter().map(|p| p.area().abs()).collect();
    (0..loops.len())
        .map(|i| {
            let probe = loops[i].vertices[0].pos();
            let depth = (0..loops.len())
                .filter(|&j| j != i && areas[j] > areas[i] && loops[j].contains(probe))
                .count();
            depth <= max_depth
        })
        .collect()
}

/// Walks a hatch's groups in order.
struct Reader<'g, 'e> {
    e: &'e Entity<'g>,
    gs: &'g [Group],
    i: usize,
    file: &'e str,
    /// The hatch as messages name it.
    who: String,
    /// The boundary path being read (0-based, for messages).
    path: usize,
}

impl<'g> Reader<'g, '_> {
    fn peek(&self) -> Option<i32> {
        self.gs.get(self.i).map(|g| g.code)
    }
    fn int_of(&self, g: &Group) -> Result<i64, ImportError> {
        g.value.parse::<i64>().map_err(|_| {
            ImportError::invalid(
                self.file,
                format!(
                    "{}: group {} on line {} is not a whole number: \"{}\"",
                    self.who,
                    g.code,
                    g.line + 1,
                    g.value.chars().take(40).collect::<String>()
                ),
            )
        })
    }
    /// The next group, which must have `code` (`what` names it in the error).
    fn need(&mut self, code: i32, what: &str) -> Result<&'g Group, ImportError> {
        let gs: &'g [Group] = self.gs;
        match gs.get(self.i) {
            Some(g) if g.code == code => {
                self.i += 1;
                Ok(g)
            }
            found => {
                let found = match found {
                    Some(g) => format!("group {} on line {}", g.code, g.line),
                    None => "the end of the entity".to_string(),
                };
                Err(ImportError::invalid(
                    self.file,
                    format!(
                        "{}: boundary path {} lacks group {code} ({what}); found {found}",
                        self.who, self.path
                    ),
                ))
            }
        }
    }
    fn need_num(&mut self, code: i32, what: &str) -> Result<f64, ImportError> {
        let g = self.need(code, what)?;
        parse_num(g, self.file, self.e)
    }
    fn need_int(&mut self, code: i32, what: &str) -> Result<i64, ImportError> {
        let g = self.need(code, what)?;
        self.int_of(g)
    }
    fn need_point(&mut self, x: i32, what: &str) -> Result<Point, ImportError> {
        Ok(Point::new(
            self.need_num(x, what)?,
            self.need_num(x + 10, what)?,
        ))
    }
    /// The next group's number when it has `code`.
    fn take_num(&mut self, code: i32) -> Result<Option<f64>, ImportError> {
        if self.peek() == Some(code) {
            self.need_num(code, "").map(Some)
        } else {
            Ok(None)
        }
    }
    fn take_int(&mut self, code: i32) -> Result<Option<i64>, ImportError> {
        if self.peek() == Some(code) {
            self.need_int(code, "").map(Some)
        } else {
            Ok(None)
        }
    }
    /// An angle in degrees as radians, refused beyond ±[`flatten::MAX_ANGLE`].
    fn need_angle(&mut self, code: i32, what: &str) -> Result<f64, ImportError> {
        let v = self.need_num(code, what)?;
        if v.abs() > flatten::MAX_ANGLE {
            return Err(self.error(format!(
                "has an angle of {v} degrees (group {code}), beyond ±{} degrees",
                flatten::MAX_ANGLE
            )));
        }
        Ok(v.to_radians())
    }
    fn error(&self, what: String) -> ImportError {
        ImportError::invalid(
            self.file,
            format!("{}: boundary path {} {what}", self.who, self.path),
        )
    }

    /// A polyline path (after its 92): 72 has bulges, 73 closed, 93 count, then 10/20
    /// (and 42) per vertex. Always a loop: a hatch boundary encloses its area.
    fn polyline_path(&mut self) -> Result<Option<Loop>, ImportError> {
        self.take_int(72)?;
        self.take_int(73)?;
        self.take_int(93)?;
        let mut vs = Vec::new();
        while self.peek() == Some(10) {
            let p = self.need_point(10, "a vertex")?;
            let bulge = self.take_num(42)?.unwrap_or(0.0);
            vs.push(Vertex::new(p.x, p.y, bulge));
        }
        Ok(super::poly(vs, true).map(|polyline| Loop {
            polyline,
            flattened: false,
        }))
    }

    /// An edge path (after its 92): 93 edges, each led by 72 (1 line, 2 arc, 3 elliptic
    /// arc, 4 spline), as open pieces (true beside those flattened from curves).
    fn edge_path(&mut self, ltol: f64, tol_mm: f64) -> Result<Vec<(Polyline, bool)>, ImportError> {
        let count = self.need_int(93, "the number of edges")?;
        let mut out = Vec::new();
        let mut k = 0i64;
        while k < count && self.peek() == Some(72) {
            k += 1;
            let kind = self.need_int(72, "the edge type")?;
            match kind {
                1 => {
                    let a = self.need_point(10, "a line's start")?;
                    let b = self.need_point(11, "a line's end")?;
                    if a.dist(b) > 0.0 {
                        out.push((Polyline::from_points(&[a, b], false), false));
                    }
                }
                2 => {
                    let c = self.need_point(10, "an arc's centre")?;
                    let r = self.need_num(40, "an arc's radius")?;
                    let (a0, a1) = (
                        self.need_angle(50, "an arc's start angle")?,
                        self.need_angle(51, "an arc's end angle")?,
                    );
                    let ccw = self.take_int(73)?.unwrap_or(1) != 0;
                    if r <= 0.0 {
                        return Err(self.error(format!(
                            "has an arc edge of radius {r}; a radius must be more than 0"
                        )));
                    }
                    out.push((self.arc(c, Point::new(r, 0.0), 1.0, a0, a1, ccw, ltol, tol_mm)?, false));
                }
                3 => {
                    let c = self.need_point(10, "an elliptic arc's centre")?;
                    let major = self.need_point(11, "an elliptic arc's major axis")?;
                    let ratio = self.need_num(40, "an elliptic arc's axis ratio")?;
                    let (a0, a1) = (
                        self.need_angle(50, "an elliptic arc's start angle")?,
                        self.need_angle(51, "an elliptic arc's end angle")?,
                    );
                    let ccw = self.take_int(73)?.unwrap_or(1) != 0;
                    if major.len() <= 0.0 || ratio <= 0.0 || ratio > 1.0 + 1e-9 {
                        return Err(self.error(format!(
                            "has an elliptic arc edge with a zero major axis or an axis ratio {ratio} outside (0, 1]"
                        )));
                    }
                    // the stored angles are angles from the major axis; the curve's
                    // parameter is the angle on the circle it was squashed from
                    // (in the same quadrant, so the same turn as the angle)
                    let param = |a: f64| {
                        let t = (a.sin() / ratio).atan2(a.cos());
                        t + ((a - t) / std::f64::consts::TAU).round() * std::f64::consts::TAU
                    };
                    let (t0, t1) = (param(a0), param(a1));
                    out.push((self.arc(c, major, ratio, t0, t1, ccw, ltol / 2.0, tol_mm)?, true));
                }
                4 => {
                    if let Some(pl) = self.spline(ltol / 2.0, tol_mm)? {
                        out.push((pl, true));
                    }
                }
                other => {
                    return Err(self.error(format!(
                        "has an edge of type {other}; known are 1 (line), 2 (arc), 3 (elliptic arc) and 4 (spline)"
                    )))
                }
            }
        }
        Ok(out)
    }

    /// A circular (ratio 1) or elliptic arc edge from `t0` to `t1`. The DXF stores a
    /// clockwise edge's angles as their complements (360° − angle): it covers the
    /// counter-clockwise sweep from −`t1` to −`t0`. Edges are joined whichever way they
    /// run, so the sweep is all that matters.
    #[allow(clippy::too_many_arguments)]
    fn arc(
        &self,
        c: Point,
        major: Point,
        ratio: f64,
        t0: f64,
        t1: f64,
        ccw: bool,
        ltol: f64,
        tol_mm: f64,
    ) -> Result<Polyline, ImportError> {
        let (t0, t1) = if ccw { (t0, t1) } else { (-t1, -t0) };
        let v = flatten::elliptical_arc(c, major, ratio, t0, t1, ltol).map_err(|err| {
            self.error(match err {
                flatten::FlattenError::TooManyPoints { .. } => format!(
                    "has a curve that would need more than {} points to stay within {tol_mm} mm; check its size or use a coarser tolerance",
                    flatten::MAX_POINTS
                ),
                other => format!("has an edge that {other}"),
            })
        })?;
        let mut pl = Polyline::new(v, false);
        super::close_if_full(&mut pl, ltol);
        Ok(pl)
    }

    /// A spline edge (after its 72): 94 degree, 73 rational, 74 periodic, 95 and 96
    /// counts, 40 knots, 10/20 control points (each with 42 when rational), then
    /// optional fit data (97, 11/21) and tangents (12/22, 13/23). None when the data make
    /// no curve.
    fn spline(&mut self, ltol: f64, tol_mm: f64) -> Result<Option<Polyline>, ImportError> {
        let degree = self.need_int(94, "a spline's degree")?.clamp(0, 32) as usize;
        for code in [73, 74, 95, 96] {
            self.take_int(code)?;
        }
        let mut knots = Vec::new();
        while let Some(k) = self.take_num(40)? {
            knots.push(k);
        }
        let (mut ctrl, mut weights) = (Vec::new(), Vec::new());
        while self.peek() == Some(10) {
            ctrl.push(self.need_point(10, "a spline's control point")?);
            if let Some(w) = self.take_num(42)? {
                weights.push(w);
            }
        }
        // fit data: a count that AutoCAD 2010 and later always write, then the points
        let mut fit = Vec::new();
        if self.peek() == Some(97) && self.gs.get(self.i + 1).map(|g| g.code) != Some(330) {
            self.i += 1;
            while self.peek() == Some(11) {
                fit.push(self.need_point(11, "a spline's fit point")?);
            }
        }
        for code in [12, 13] {
            if self.peek() == Some(code) {
                self.need_point(code, "a spline's tangent")?;
            }
        }
        let pts = if !ctrl.is_empty() {
            match flatten::nurbs(degree, &knots, &ctrl, &weights, ltol) {
                Ok(p) => p,
                Err(flatten::FlattenError::NotACurve) => {
                    return Err(self.error(
                        "has a spline edge whose knots, weights and control points do not make a curve"
                            .to_string(),
                    ))
                }
                Err(flatten::FlattenError::TooManyPoints { .. }) => {
                    return Err(self.error(format!(
                        "has a spline edge that would need more than {} points to stay within {tol_mm} mm",
                        flatten::MAX_POINTS
                    )))
                }
                Err(other) => return Err(self.error(format!("has a spline edge that {other}"))),
            }
        } else if fit.len() >= 2 {
            fit
        } else {
            return Ok(None);
        };
        let mut pl = Polyline::from_points(&pts, false);
        super::close_if_full(&mut pl, ltol.max(1e-9));
        Ok(Some(pl))
    }
}
