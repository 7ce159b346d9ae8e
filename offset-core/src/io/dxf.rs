//! DXF import (ASCII, R12 to 2018): LINE, ARC, CIRCLE, LWPOLYLINE, POLYLINE/VERTEX, SPLINE and ELLIPSE from the ENTITIES section, chained into contours, in mm.
//!
//! Our own group-code reader rather than a full DXF library: it only needs the entity
//! geometry, it must never panic on a broken file, and it stops at `0 EOF` (what follows
//! is ignored). Entities of other types (TEXT, INSERT, 3DFACE, …) are skipped and counted
//! in the warnings. Units come from `$INSUNITS` (unitless drawings are taken as mm).
//! Problems that leave a usable drawing (open contours, gaps, duplicates, crossings,
//! skipped entities) are warnings with their location; problems that make an entity
//! meaningless (a CIRCLE or ARC with radius ≤ 0, a coordinate that is not a number)
//! are errors naming the entity by handle and line.

use super::chain::{chain, self_intersections};
use super::ImportError;
use crate::flatten;
use crate::geom::{Point, Polyline, Shape, Vertex};
use std::collections::BTreeMap;

/// How to read a DXF file.
#[derive(Clone, Debug, PartialEq)]
pub struct DxfOptions {
    /// Read only entities on these layers (all layers when empty). Layer names compare
    /// case-insensitively, as in CAD programs.
    pub layers: Vec<String>,
    /// Ends of loose entities closer than this are joined, and curves are flattened within
    /// it, mm.
    pub tolerance: f64,
}

impl Default for DxfOptions {
    fn default() -> Self {
        DxfOptions {
            layers: Vec::new(),
            tolerance: 1e-3,
        }
    }
}

/// A drawing read from DXF, with what the reader noticed.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DxfDrawing {
    pub shape: Shape,
    /// mm per drawing unit, from `$INSUNITS`.
    pub scale: f64,
    pub warnings: Vec<String>,
}

/// Reads a DXF file with default options.
pub fn read(bytes: &[u8], file: &str) -> Result<Shape, ImportError> {
    read_with(bytes, file, &DxfOptions::default()).map(|d| d.shape)
}

/// One group: code, value, and the line of the code (1-based).
struct Group {
    code: i32,
    value: String,
    line: usize,
}

fn groups(bytes: &[u8], file: &str) -> Result<Vec<Group>, ImportError> {
    if bytes.starts_with(b"AutoCAD Binary DXF") {
        return Err(ImportError::invalid(
            file,
            "binary DXF is not supported; save the drawing as ASCII DXF",
        ));
    }
    let text = String::from_utf8_lossy(bytes);
    let text = text.strip_prefix('\u{feff}').unwrap_or(&text);
    let mut lines = text.lines().enumerate();
    let mut out = Vec::new();
    while let Some((n, code)) = lines.next() {
        let code_s = code.trim();
        if code_s.is_empty() && out.is_empty() {
            continue;
        }
        let Some((_, value)) = lines.next() else {
            if code_s.is_empty() {
                break;
            }
            return Err(ImportError::invalid(
                file,
                format!("line {}: group code {code_s} has no value", n + 1),
            ));
        };
        let code: i32 = code_s.parse().map_err(|_| {
            ImportError::invalid(
                file,
                format!(
                    "line {}: expected a group code (a number), found \"{}\"",
                    n + 1,
                    code_s.chars().take(40).collect::<String>()
                ),
            )
        })?;
        let value = value.trim().to_string();
        let eof = code == 0 && value == "EOF";
        out.push(Group {
            code,
            value,
            line: n + 1,
        });
        if eof {
            break; // whatever follows EOF is not part of the drawing
        }
    }
    Ok(out)
}

/// One entity: its type, the groups after its `0 TYPE`, and the line it starts on.
struct Entity<'a> {
    kind: &'a str,
    groups: &'a [Group],
    line: usize,
}

impl Entity<'_> {
    fn handle(&self) -> String {
        self.groups
            .iter()
            .find(|g| g.code == 5)
            .map(|g| format!("{} (handle {}, line {})", self.kind, g.value, self.line))
            .unwrap_or_else(|| format!("{} (line {})", self.kind, self.line))
    }
    fn layer(&self) -> &str {
        self.groups
            .iter()
            .find(|g| g.code == 8)
            .map_or("0", |g| g.value.as_str())
    }
    fn num(&self, code: i32, file: &str) -> Result<Option<f64>, ImportError> {
        match self.groups.iter().find(|g| g.code == code) {
            None => Ok(None),
            Some(g) => parse_num(g, file, self).map(Some),
        }
    }
    fn req(&self, code: i32, file: &str) -> Result<f64, ImportError> {
        self.num(code, file)?.ok_or_else(|| {
            ImportError::invalid(file, format!("{} has no group {code}", self.handle()))
        })
    }
    /// An angle (or ellipse parameter) in `unit`s, refused beyond ±[`flatten::MAX_ANGLE`]:
    /// so far out, a turn is lost in the rounding.
    fn angle(&self, code: i32, file: &str, unit: &str) -> Result<Option<f64>, ImportError> {
        let Some(g) = self.groups.iter().find(|g| g.code == code) else {
            return Ok(None);
        };
        let v = parse_num(g, file, self)?;
        if v.abs() > flatten::MAX_ANGLE {
            return Err(ImportError::invalid(
                file,
                format!(
                    "{} has an angle of {} {unit} (group {code} on line {}), beyond ±{} {unit}",
                    self.handle(),
                    g.value.chars().take(40).collect::<String>(),
                    g.line + 1,
                    flatten::MAX_ANGLE
                ),
            ));
        }
        Ok(Some(v))
    }
    fn req_angle(&self, code: i32, file: &str, unit: &str) -> Result<f64, ImportError> {
        self.angle(code, file, unit)?.ok_or_else(|| {
            ImportError::invalid(file, format!("{} has no group {code}", self.handle()))
        })
    }
    /// What went wrong flattening this entity, in one sentence (`tol`: the tolerance, mm).
    fn curve_error(&self, file: &str, err: flatten::FlattenError, tol: f64) -> ImportError {
        let what = match err {
            flatten::FlattenError::TooManyPoints { .. } => format!(
                "would need more than {} points to stay within {tol} mm of the curve; check its size or use a coarser tolerance",
                flatten::MAX_POINTS
            ),
            other => other.to_string(),
        };
        ImportError::invalid(file, format!("{} {what}", self.handle()))
    }
    fn int(&self, code: i32) -> i64 {
        self.groups
            .iter()
            .find(|g| g.code == code)
            .and_then(|g| g.value.parse::<i64>().ok())
            .unwrap_or(0)
    }
    /// +1, or -1 when the entity's extrusion direction points down (its OCS mirrors X).
    fn ocs_x(&self, file: &str) -> Result<f64, ImportError> {
        Ok(match self.num(230, file)? {
            Some(z) if z < 0.0 => -1.0,
            _ => 1.0,
        })
    }
}

/// The number in group `g` of entity `e` (named only in the error: finding the handle
/// takes a walk over the entity's groups).
fn parse_num(g: &Group, file: &str, e: &Entity) -> Result<f64, ImportError> {
    match g.value.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(ImportError::invalid(
            file,
            format!(
                "{}: group {} on line {} is not a number: \"{}\"",
                e.handle(),
                g.code,
                g.line + 1,
                g.value.chars().take(40).collect::<String>()
            ),
        )),
    }
}

/// Reads a DXF file: the entities of the ENTITIES section on the chosen layers, in mm.
pub fn read_with(bytes: &[u8], file: &str, opts: &DxfOptions) -> Result<DxfDrawing, ImportError> {
    let gs = groups(bytes, file)?;
    let tol = if opts.tolerance.is_finite() && opts.tolerance > 0.0 {
        opts.tolerance
    } else {
        1e-3
    };
    // split at every group 0 into records, noting the section each lies in
    let mut scale = 1.0;
    let mut warnings = Vec::new();
    let mut section = String::new();
    let mut records: Vec<Entity> = Vec::new();
    let mut i = 0;
    while i < gs.len() {
        if gs[i].code != 0 {
            i += 1;
            continue;
        }
        let start = i;
        i += 1;
        while i < gs.len() && gs[i].code != 0 {
            i += 1;
        }
        let kind = gs[start].value.as_str();
        let body = &gs[start + 1..i];
        match kind {
            "SECTION" => {
                section = body
                    .iter()
                    .find(|g| g.code == 2)
                    .map(|g| g.value.to_ascii_uppercase())
                    .unwrap_or_default();
                if section == "HEADER" {
                    scale = header_scale(body, &mut warnings);
                }
            }
            "ENDSEC" => section.clear(),
            _ if section == "ENTITIES" => records.push(Entity {
                kind,
                groups: body,
                line: gs[start].line,
            }),
            _ => {}
        }
    }
    let wanted = |e: &Entity| {
        opts.layers.is_empty()
            || opts
                .layers
                .iter()
                .any(|l| l.eq_ignore_ascii_case(e.layer()))
    };
    let ftol = tol / scale; // flattening tolerance in drawing units
    let mut pieces: Vec<Polyline> = Vec::new();
    let mut skipped: BTreeMap<String, usize> = BTreeMap::new();
    let mut curve_points = 0; // points flattened from ELLIPSEs and SPLINEs so far
    let mut k = 0;
    while k < records.len() {
        let e = &records[k];
        k += 1;
        if e.kind == "POLYLINE" {
            // old-style polyline: VERTEX records up to SEQEND
            let mut verts = Vec::new();
            while k < records.len() && records[k].kind == "VERTEX" {
                verts.push(&records[k]);
                k += 1;
            }
            if k < records.len() && records[k].kind == "SEQEND" {
                k += 1;
            }
            if !wanted(e) {
                continue;
            }
            let flags = e.int(70);
            if flags & (16 | 64) != 0 {
                *skipped.entry("POLYLINE mesh".into()).or_default() += 1;
                continue;
            }
            let mut vs = Vec::new();
            for v in verts {
                if v.int(70) & 16 != 0 {
                    continue; // spline frame control point, not on the curve
                }
                let x = v.req(10, file)?;
                let y = v.req(20, file)?;
                let b = v.num(42, file)?.unwrap_or(0.0);
                vs.push(Vertex::new(x, y, b));
            }
            push_poly(&mut pieces, vs, flags & 1 != 0, e.ocs_x(file)?);
            continue;
        }
        if !wanted(e) {
            continue;
        }
        match e.kind {
            "LINE" => {
                let a = Point::new(e.req(10, file)?, e.req(20, file)?);
                let b = Point::new(e.req(11, file)?, e.req(21, file)?);
                if a.dist(b) > 0.0 {
                    pieces.push(Polyline::from_points(&[a, b], false));
                }
            }
            "ARC" | "CIRCLE" => {
                let sx = e.ocs_x(file)?;
                let c = Point::new(e.req(10, file)? * sx, e.req(20, file)?);
                let r = e.req(40, file)?;
                if r <= 0.0 {
                    return Err(ImportError::invalid(
                        file,
                        format!(
                            "{} has radius {r}; a radius must be more than 0",
                            e.handle()
                        ),
                    ));
                }
                if e.kind == "CIRCLE" {
                    pieces.push(Polyline::circle(c, r));
                } else {
                    let (mut a0, mut a1) = (
                        e.req_angle(50, file, "degrees")?.to_radians(),
                        e.req_angle(51, file, "degrees")?.to_radians(),
                    );
                    if sx < 0.0 {
                        // mirrored OCS: the arc runs clockwise in world coordinates
                        (a0, a1) = (std::f64::consts::PI - a1, std::f64::consts::PI - a0);
                    }
                    let v = flatten::elliptical_arc(c, Point::new(r, 0.0), 1.0, a0, a1, ftol)
                        .map_err(|err| e.curve_error(file, err, tol))?;
                    pieces.push(Polyline::new(v, false));
                }
            }
            "LWPOLYLINE" => {
                let mut vs: Vec<Vertex> = Vec::new();
                for g in e.groups {
                    match g.code {
                        10 => vs.push(Vertex::new(parse_num(g, file, e)?, 0.0, 0.0)),
                        20 => {
                            if let Some(v) = vs.last_mut() {
                                v.y = parse_num(g, file, e)?;
                            }
                        }
                        42 => {
                            if let Some(v) = vs.last_mut() {
                                v.bulge = parse_num(g, file, e)?;
                            }
                        }
                        _ => {}
                    }
                }
                push_poly(&mut pieces, vs, e.int(70) & 1 != 0, e.ocs_x(file)?);
            }
            "ELLIPSE" => {
                let c = Point::new(e.req(10, file)?, e.req(20, file)?);
                let major = Point::new(e.req(11, file)?, e.req(21, file)?);
                let ratio = e.req(40, file)?;
                let t0 = e.angle(41, file, "radians")?.unwrap_or(0.0);
                let t1 = e
                    .angle(42, file, "radians")?
                    .unwrap_or(std::f64::consts::TAU);
                if major.len() <= 0.0 || ratio <= 0.0 || ratio > 1.0 + 1e-9 {
                    return Err(ImportError::invalid(
                        file,
                        format!(
                            "{} has a zero major axis or an axis ratio {ratio} outside (0, 1]",
                            e.handle()
                        ),
                    ));
                }
                let sx = e.ocs_x(file)?;
                let v = flatten::elliptical_arc(c, major, ratio * sx, t0, t1, ftol)
                    .map_err(|err| e.curve_error(file, err, tol))?;
                let mut pl = Polyline::new(v, false);
                if sx < 0.0 {
                    pl = mirror_x(pl);
                }
                close_if_full(&mut pl, ftol);
                spend(&mut curve_points, pl.len(), e, file, tol)?;
                pieces.push(pl);
            }
            "SPLINE" => match spline(e, file, ftol, tol)? {
                Some(pl) => {
                    spend(&mut curve_points, pl.len(), e, file, tol)?;
                    pieces.push(pl)
                }
                None => warnings.push(format!(
                    "{} has inconsistent knots, weights or points and was skipped",
                    e.handle()
                )),
            },
            "SEQEND" | "VERTEX" | "ATTRIB" => {}
            other => *skipped.entry(other.to_string()).or_default() += 1,
        }
    }
    for (kind, n) in skipped {
        warnings.push(format!(
            "{n} {kind} entit{} skipped (no geometry we cut)",
            if n == 1 { "y" } else { "ies" }
        ));
    }
    // to mm, then chain
    let pieces: Vec<Polyline> = pieces
        .into_iter()
        .map(|mut p| {
            for v in &mut p.vertices {
                v.x *= scale;
                v.y *= scale;
            }
            p
        })
        .collect();
    let paths = chain(pieces, tol, &mut warnings);
    for (i, p) in paths.iter().enumerate() {
        if p.closed {
            for x in self_intersections(p, 3) {
                warnings.push(format!(
                    "contour {i} crosses itself near ({:.4}, {:.4})",
                    x.x, x.y
                ));
            }
        }
    }
    if !opts.layers.is_empty() && paths.is_empty() {
        return Err(ImportError::invalid(
            file,
            format!("no geometry on layer(s) {}", opts.layers.join(", ")),
        ));
    }
    Ok(DxfDrawing {
        shape: Shape::new(paths),
        scale,
        warnings,
    })
}

/// Counts the `n` points entity `e` was flattened into against the drawing's budget of
/// [`flatten::MAX_DRAWING_POINTS`] (`tol`: the tolerance, mm, for the message).
fn spend(total: &mut usize, n: usize, e: &Entity, file: &str, tol: f64) -> Result<(), ImportError> {
    *total += n;
    if *total > flatten::MAX_DRAWING_POINTS {
        return Err(ImportError::invalid(
            file,
            format!(
                "the drawing's curves would need more than {} points in all to stay within {tol} mm (reached at {}); use a coarser tolerance",
                flatten::MAX_DRAWING_POINTS,
                e.handle()
            ),
        ));
    }
    Ok(())
}

/// mm per drawing unit from the header's `$INSUNITS` (group 70 after it).
fn header_scale(body: &[Group], warnings: &mut Vec<String>) -> f64 {
    let Some(pos) = body
        .iter()
        .position(|g| g.code == 9 && g.value == "$INSUNITS")
    else {
        return 1.0;
    };
    let code = body
        .get(pos + 1)
        .filter(|g| g.code == 70)
        .and_then(|g| g.value.parse::<i64>().ok())
        .unwrap_or(0);
    match code {
        0 | 4 => 1.0,
        1 => 25.4,
        2 => 304.8,
        3 => 1_609_344.0,
        5 => 10.0,
        6 => 1000.0,
        7 => 1_000_000.0,
        8 => 25.4e-6,
        9 => 25.4e-3,
        10 => 914.4,
        13 => 1e-3,
        14 => 100.0,
        other => {
            warnings.push(format!(
                "$INSUNITS {other} is not a length unit we know; read as mm"
            ));
            1.0
        }
    }
}

fn push_poly(pieces: &mut Vec<Polyline>, mut vs: Vec<Vertex>, closed: bool, sx: f64) {
    vs.dedup_by(|b, a| a.x == b.x && a.y == b.y);
    if closed && vs.len() > 2 && vs[0].pos() == vs[vs.len() - 1].pos() {
        vs.pop();
    }
    if vs.len() < 2 {
        return;
    }
    if !closed {
        if let Some(v) = vs.last_mut() {
            v.bulge = 0.0;
        }
    }
    let pl = Polyline::new(vs, closed);
    pieces.push(if sx < 0.0 { mirror_x(pl) } else { pl });
}

/// Mirrors X (a downward extrusion direction): arcs turn the other way.
fn mirror_x(mut pl: Polyline) -> Polyline {
    for v in &mut pl.vertices {
        v.x = -v.x;
        v.bulge = -v.bulge;
    }
    pl
}

fn close_if_full(pl: &mut Polyline, tol: f64) {
    let n = pl.len();
    if n > 2 && pl.vertices[0].pos().dist(pl.vertices[n - 1].pos()) <= tol {
        pl.vertices.pop();
        pl.closed = true;
    }
}

/// A SPLINE as a polyline: the NURBS from its control points, or its fit points when it
/// has none.
/// `tol` is in drawing units, `tol_mm` the same in mm (for messages).
fn spline(e: &Entity, file: &str, tol: f64, tol_mm: f64) -> Result<Option<Polyline>, ImportError> {
    let degree = e.int(71).clamp(0, 32) as usize;
    let mut knots = Vec::new();
    let mut weights = Vec::new();
    let mut ctrl: Vec<Point> = Vec::new();
    let mut fit: Vec<Point> = Vec::new();
    for g in e.groups {
        match g.code {
            40 => knots.push(parse_num(g, file, e)?),
            41 => weights.push(parse_num(g, file, e)?),
            10 => ctrl.push(Point::new(parse_num(g, file, e)?, 0.0)),
            20 => {
                if let Some(p) = ctrl.last_mut() {
                    p.y = parse_num(g, file, e)?;
                }
            }
            11 => fit.push(Point::new(parse_num(g, file, e)?, 0.0)),
            21 => {
                if let Some(p) = fit.last_mut() {
                    p.y = parse_num(g, file, e)?;
                }
            }
            _ => {}
        }
    }
    let pts = if !ctrl.is_empty() {
        match flatten::nurbs(degree, &knots, &ctrl, &weights, tol) {
            Ok(p) => p,
            Err(flatten::FlattenError::NotACurve) => return Ok(None),
            Err(err) => return Err(e.curve_error(file, err, tol_mm)),
        }
    } else if fit.len() >= 2 {
        fit
    } else {
        return Ok(None);
    };
    let mut pl = Polyline::from_points(&pts, false);
    if e.int(70) & 1 != 0 || pts[0].dist(pts[pts.len() - 1]) <= tol {
        close_if_full(&mut pl, tol.max(1e-9));
    }
    Ok(Some(if e.ocs_x(file)? < 0.0 {
        mirror_x(pl)
    } else {
        pl
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dxf(entities: &str) -> String {
        format!("0\nSECTION\n2\nENTITIES\n{entities}0\nENDSEC\n0\nEOF\n")
    }

    #[test]
    fn lines_and_arc_chain_and_layers_filter() {
        let src = dxf("0\nLINE\n8\nCUT\n10\n0\n20\n0\n11\n10\n21\n0\n0\nARC\n8\nCUT\n10\n10\n20\n5\n40\n5\n50\n270\n51\n90\n0\nLINE\n8\nCUT\n10\n10\n20\n10\n11\n0\n21\n10\n0\nLINE\n8\nCUT\n10\n0\n20\n10\n11\n0\n21\n0\n0\nCIRCLE\n8\nOTHER\n10\n50\n20\n50\n40\n2\n");
        let all = read(src.as_bytes(), "t.dxf").unwrap();
        assert_eq!(all.paths.len(), 2);
        let d = read_with(
            src.as_bytes(),
            "t.dxf",
            &DxfOptions {
                layers: vec!["cut".into()],
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!(d.shape.paths.len(), 1);
        let p = &d.shape.paths[0];
        assert!(p.closed);
        let expect = 100.0 + std::f64::consts::PI * 25.0 / 2.0;
        assert!((p.area().abs() - expect).abs() < 1e-9, "{}", p.area());
    }

    #[test]
    fn bad_numbers_and_radii_are_errors_that_say_where() {
        let e = read(
            dxf("0\nCIRCLE\n5\n2A\n10\n0\n20\n0\n40\n-1\n").as_bytes(),
            "c.dxf",
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("CIRCLE (handle 2A") && e.contains("radius -1"),
            "{e}"
        );
        let e = read(
            dxf("0\nLINE\n10\nabc\n20\n0\n11\n1\n21\n0\n").as_bytes(),
            "l.dxf",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("LINE") && e.contains("not a number"), "{e}");
    }
}
