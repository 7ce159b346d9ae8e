//! DXF import (ASCII and binary, R12 to 2018): LINE, ARC, CIRCLE, LWPOLYLINE, POLYLINE/VERTEX, SPLINE, ELLIPSE and HATCH boundaries from the ENTITIES section and the blocks it inserts, chained into contours, in mm.
//!
//! Our own group-code reader rather than a full DXF library: it only needs the entity
//! geometry, it must never panic on a broken file, and it stops at `0 EOF` (what follows
//! is ignored); a binary file ([`binary`]) becomes the same groups. A HATCH's boundary
//! paths ([`hatch`]) become closed loops, chosen by the hatch's style. INSERT places a block (its base point on the insertion point, X and Y
//! scales, rotation, MINSERT arrays of columns and rows, extrusion mirrored or not), and
//! blocks may insert blocks: they are read from a work list, never by recursion, to a
//! depth of [`MAX_NESTING`] and at most [`MAX_PLACEMENTS`] instances. Entities on layer 0
//! inside a block take the INSERT's layer. Entities of other types (TEXT, 3DFACE, …) are
//! skipped and counted in the warnings. Units come from `$INSUNITS` (unitless drawings are
//! taken as mm). Polylines are fitted with lines and arcs within the tolerance, curves are
//! flattened within half of it and fitted within the other half.
//! Problems that leave a usable drawing (open contours, gaps, duplicates, crossings,
//! skipped entities, undefined blocks) are warnings with their location; problems that make
//! an entity meaningless (a CIRCLE or ARC with radius ≤ 0, a coordinate that is not a
//! number) are errors naming the entity by handle and line.

mod binary;
mod hatch;

use super::chain::{chain, self_intersections};
use super::ImportError;
use crate::flatten;
use crate::geom::{Point, Polyline, Segment, Shape, Vertex};
use std::collections::{BTreeMap, HashMap};

/// How to read a DXF file.
#[derive(Clone, Debug, PartialEq)]
pub struct DxfOptions {
    /// Read only entities on these layers (all layers when empty). Layer names compare
    /// case-insensitively, as in CAD programs.
    pub layers: Vec<String>,
    /// Ends of loose entities closer than this are joined, curves are flattened within it,
    /// and polylines fitted with arcs within it, mm.
    pub tolerance: f64,
    /// Fit polylines (LWPOLYLINE, POLYLINE) and flattened curves (SPLINE, ELLIPSE) with
    /// lines and arcs ([`crate::biarc`]); when false they come as the points they are or
    /// were flattened into.
    pub fit: bool,
    /// Read only entities of these colours (AutoCAD colour numbers; an entity without its
    /// own colour, or BYLAYER, takes its layer's from the LAYER table); all when empty.
    pub colors: Vec<i64>,
}

impl Default for DxfOptions {
    fn default() -> Self {
        DxfOptions {
            layers: Vec::new(),
            tolerance: 1e-3,
            fit: true,
            colors: Vec::new(),
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
    /// Each piece as read, before chaining, with the entity it came from as messages name
    /// it (`LINE (handle 2A, line 120) on layer CUT`).
    pieces: Vec<(Polyline, String)>,
}

impl DxfDrawing {
    /// The entities whose geometry passes within `within` mm of `at` (a crossing, say), as
    /// messages name them, each once, at most `max`.
    pub fn entities_at(&self, at: Point, within: f64, max: usize) -> Vec<String> {
        let mut out: Vec<String> = Vec::new();
        for (pl, name) in &self.pieces {
            if out.len() == max {
                break;
            }
            if pl.distance_to(at) <= within && !out.contains(name) {
                out.push(name.clone());
            }
        }
        out
    }
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
    if bytes.starts_with(binary::SENTINEL) {
        return binary::groups(bytes, file);
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
    /// An error placing this entity in the drawing (`what` ends the sentence).
    fn placed_error(&self, file: &str, what: String) -> ImportError {
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

/// An entity's colour number: its own (group 62), else (absent, 0 BYBLOCK or 256 BYLAYER)
/// its layer's from the LAYER table, else 7.
fn entity_color(e: &Entity, layer: &str, layer_colors: &HashMap<String, i64>) -> i64 {
    match e.int(62) {
        0 | 256 => layer_colors
            .get(&layer.to_uppercase())
            .copied()
            .filter(|&c| c > 0 && c < 256)
            .unwrap_or(7),
        c => c.abs(),
    }
}

/// One entity of a drawing's ENTITIES section as a recipe sees it: what it is, where, and
/// for circles and points, the hole it makes.
#[derive(Clone, Debug, PartialEq)]
pub struct DxfEntity {
    /// The entity type (`CIRCLE`, `LINE`, `POINT`, `INSERT`, …).
    pub kind: String,
    pub layer: String,
    /// The entity's handle (group 5), when it has one.
    pub handle: Option<String>,
    /// The line of the file its record starts on.
    pub line: usize,
    /// Its colour number (see [`DxfOptions::colors`]).
    pub color: i64,
    /// A CIRCLE's or POINT's centre, mm.
    pub center: Option<Point>,
    /// A CIRCLE's diameter, mm (0 for a POINT).
    pub diameter: f64,
}

impl DxfEntity {
    /// The entity as messages name it: `CIRCLE (handle 2A, line 120) on layer HOLES`.
    pub fn describe(&self) -> String {
        match &self.handle {
            Some(h) => format!(
                "{} (handle {h}, line {}) on layer {}",
                self.kind, self.line, self.layer
            ),
            None => format!("{} (line {}) on layer {}", self.kind, self.line, self.layer),
        }
    }
}

/// The entities of a DXF file's ENTITIES section (not those inside the blocks an INSERT
/// places, which count as the INSERT), with their layers, colours and, for circles and
/// points, centres in mm.
pub fn entities(bytes: &[u8], file: &str) -> Result<Vec<DxfEntity>, ImportError> {
    let gs = groups(bytes, file)?;
    let mut scale = 1.0;
    let mut warnings = Vec::new();
    let mut section = String::new();
    let mut layer_colors: HashMap<String, i64> = HashMap::new();
    let mut out = Vec::new();
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
        let e = Entity {
            kind: gs[start].value.as_str(),
            groups: &gs[start + 1..i],
            line: gs[start].line,
        };
        match e.kind {
            "SECTION" => {
                section = e
                    .groups
                    .iter()
                    .find(|g| g.code == 2)
                    .map(|g| g.value.to_ascii_uppercase())
                    .unwrap_or_default();
                if section == "HEADER" {
                    scale = header_scale(e.groups, &mut warnings);
                }
            }
            "ENDSEC" => section.clear(),
            "LAYER" if section == "TABLES" => {
                if let Some(name) = e.groups.iter().find(|g| g.code == 2) {
                    layer_colors.insert(name.value.to_uppercase(), e.int(62).abs());
                }
            }
            "VERTEX" | "SEQEND" | "ATTRIB" => {}
            kind if section == "ENTITIES" => {
                let layer = e.layer().to_string();
                let (center, diameter) = match kind {
                    "CIRCLE" | "POINT" => {
                        let c = Point::new(e.req(10, file)?, e.req(20, file)?) * scale;
                        let d = if kind == "CIRCLE" {
                            2.0 * e.req(40, file)? * scale
                        } else {
                            0.0
                        };
                        let c = if e.ocs_x(file)? < 0.0 {
                            Point::new(-c.x, c.y)
                        } else {
                            c
                        };
                        (Some(c), d)
                    }
                    _ => (None, 0.0),
                };
                out.push(DxfEntity {
                    kind: kind.to_string(),
                    color: entity_color(&e, &layer, &layer_colors),
                    layer,
                    handle: e
                        .groups
                        .iter()
                        .find(|g| g.code == 5)
                        .map(|g| g.value.clone()),
                    line: e.line,
                    center,
                    diameter,
                });
            }
            _ => {}
        }
    }
    Ok(out)
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

/// Reads a DXF file: the entities of the ENTITIES section on the chosen layers, with the
/// blocks they insert, in mm.
pub fn read_with(bytes: &[u8], file: &str, opts: &DxfOptions) -> Result<DxfDrawing, ImportError> {
    let gs = groups(bytes, file)?;
    let tol = if opts.tolerance.is_finite() && opts.tolerance > 0.0 {
        opts.tolerance
    } else {
        1e-3
    };
    // split at every group 0 into records, noting the section each lies in; the BLOCKS
    // section's records are grouped into blocks by name
    let mut scale = 1.0;
    let mut warnings = Vec::new();
    let mut section = String::new();
    let mut records: Vec<Entity> = Vec::new();
    let mut blocks: HashMap<String, Block> = HashMap::new();
    let mut block: Option<(String, Block)> = None;
    let mut layer_colors: HashMap<String, i64> = HashMap::new();
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
        let rec = Entity {
            kind,
            groups: body,
            line: gs[start].line,
        };
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
            "LAYER" if section == "TABLES" => {
                if let Some(name) = body.iter().find(|g| g.code == 2) {
                    layer_colors.insert(name.value.to_uppercase(), rec.int(62).abs());
                }
            }
            _ if section == "ENTITIES" => records.push(rec),
            "BLOCK" if section == "BLOCKS" => {
                let name = body
                    .iter()
                    .find(|g| g.code == 2)
                    .map(|g| g.value.to_uppercase())
                    .unwrap_or_default();
                let base = Point::new(
                    rec.num(10, file)?.unwrap_or(0.0),
                    rec.num(20, file)?.unwrap_or(0.0),
                );
                block = Some((
                    name,
                    Block {
                        base,
                        records: Vec::new(),
                    },
                ));
            }
            "ENDBLK" if section == "BLOCKS" => {
                if let Some((name, b)) = block.take() {
                    blocks.insert(name, b);
                }
            }
            _ if section == "BLOCKS" => {
                if let Some((_, b)) = block.as_mut() {
                    b.records.push(rec);
                }
            }
            _ => {}
        }
    }
    let wanted = |layer: &str, e: &Entity| {
        (opts.layers.is_empty() || opts.layers.iter().any(|l| l.eq_ignore_ascii_case(layer)))
            && (opts.colors.is_empty()
                || opts.colors.contains(&entity_color(e, layer, &layer_colors)))
    };
    let mut pieces: Vec<Polyline> = Vec::new();
    // the entity each piece came from: pieces pushed while reading an entity get its name
    // when the next one starts (or at the end)
    let mut names: Vec<String> = Vec::new();
    let mut last_name = String::new();
    let mut skipped: BTreeMap<String, usize> = BTreeMap::new();
    let mut curve_points = 0; // points flattened from ELLIPSEs, SPLINEs and HATCHes so far
    let mut hatch_loops: Vec<Polyline> = Vec::new(); // closed, placed, chosen by style
    let mut placed = 0usize; // block instances placed so far
                             // the drawing, then every block instance it inserts: a work list, not recursion, so
                             // deep nesting costs memory in proportion, never the stack
    let mut work: Vec<Work> = vec![Work {
        records: &records,
        xf: Xf::scale(scale),
        layer: None,
        depth: 0,
    }];
    while let Some(w) = work.pop() {
        let mut k = 0;
        while k < w.records.len() {
            names.resize(pieces.len(), last_name.clone());
            let e = &w.records[k];
            k += 1;
            // an entity on layer 0 inside a block takes the layer of the INSERT
            let layer = match (e.layer(), &w.layer) {
                ("0", Some(l)) => l.clone(),
                (l, _) => l.to_string(),
            };
            last_name = format!("{} on layer {layer}", e.handle());
            let xf = if e.ocs_x(file)? < 0.0 {
                w.xf.then(&Xf::MIRROR_X)
            } else {
                w.xf
            };
            // the tolerance in this entity's own units
            let ltol = tol / xf.stretch();
            if e.kind == "POLYLINE" {
                // old-style polyline: VERTEX records up to SEQEND
                let mut verts = Vec::new();
                while k < w.records.len() && w.records[k].kind == "VERTEX" {
                    verts.push(&w.records[k]);
                    k += 1;
                }
                if k < w.records.len() && w.records[k].kind == "SEQEND" {
                    k += 1;
                }
                if !wanted(&layer, e) {
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
                if let Some(pl) = poly(vs, flags & 1 != 0) {
                    pieces
                        .push(place(pl, &xf, tol, opts.fit).map_err(|m| e.placed_error(file, m))?);
                }
                continue;
            }
            if e.kind == "INSERT" {
                let name = e
                    .groups
                    .iter()
                    .find(|g| g.code == 2)
                    .map(|g| g.value.clone())
                    .unwrap_or_default();
                let Some(b) = blocks.get(&name.to_uppercase()) else {
                    warnings.push(format!(
                        "{} inserts block \"{name}\", which the file does not define; skipped",
                        e.handle()
                    ));
                    continue;
                };
                if w.depth >= MAX_NESTING {
                    return Err(ImportError::invalid(
                        file,
                        format!(
                            "{} nests blocks more than {MAX_NESTING} deep (does block \"{name}\" insert itself?)",
                            e.handle()
                        ),
                    ));
                }
                let at = Point::new(
                    e.num(10, file)?.unwrap_or(0.0),
                    e.num(20, file)?.unwrap_or(0.0),
                );
                let (sx, sy) = (
                    e.num(41, file)?.unwrap_or(1.0),
                    e.num(42, file)?.unwrap_or(1.0),
                );
                let rot = e.angle(50, file, "degrees")?.unwrap_or(0.0).to_radians();
                let (cols, rows) = (e.int(70).max(1) as u64, e.int(71).max(1) as u64);
                let (dx, dy) = (
                    e.num(44, file)?.unwrap_or(0.0),
                    e.num(45, file)?.unwrap_or(0.0),
                );
                if sx == 0.0 || sy == 0.0 {
                    warnings.push(format!(
                        "{} inserts block \"{name}\" at scale 0; skipped",
                        e.handle()
                    ));
                    continue;
                }
                let n = cols.saturating_mul(rows);
                placed = placed.saturating_add(n as usize);
                if placed > MAX_PLACEMENTS {
                    return Err(ImportError::invalid(
                        file,
                        format!(
                            "the drawing places more than {MAX_PLACEMENTS} block instances (reached at {}); explode the arrays or split the drawing",
                            e.handle()
                        ),
                    ));
                }
                // in the INSERT's frame: the block's base to the insertion point, scaled,
                // rotated; array cells step along the rotated axes
                let (c, s) = (rot.cos(), rot.sin());
                for row in 0..rows {
                    for col in 0..cols {
                        let off = Point::new(col as f64 * dx, row as f64 * dy);
                        let origin = at + Point::new(c * off.x - s * off.y, s * off.x + c * off.y);
                        let inst = Xf {
                            a: c * sx,
                            b: -s * sy,
                            c: s * sx,
                            d: c * sy,
                            t: Point::default(),
                        };
                        let t = origin - inst.apply(b.base);
                        work.push(Work {
                            records: &b.records,
                            xf: xf.then(&Xf { t, ..inst }),
                            layer: Some(layer.clone()),
                            depth: w.depth + 1,
                        });
                    }
                }
                continue;
            }
            if !wanted(&layer, e) {
                continue;
            }
            match e.kind {
                "LINE" => {
                    let a = Point::new(e.req(10, file)?, e.req(20, file)?);
                    let b = Point::new(e.req(11, file)?, e.req(21, file)?);
                    if a.dist(b) > 0.0 {
                        let pl = Polyline::from_points(&[a, b], false);
                        pieces
                            .push(place(pl, &xf, tol, false).map_err(|m| e.placed_error(file, m))?);
                    }
                }
                "ARC" | "CIRCLE" => {
                    let c = Point::new(e.req(10, file)?, e.req(20, file)?);
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
                    let pl = if e.kind == "CIRCLE" {
                        Polyline::circle(c, r)
                    } else {
                        let (a0, a1) = (
                            e.req_angle(50, file, "degrees")?.to_radians(),
                            e.req_angle(51, file, "degrees")?.to_radians(),
                        );
                        let v = flatten::elliptical_arc(c, Point::new(r, 0.0), 1.0, a0, a1, ltol)
                            .map_err(|err| e.curve_error(file, err, tol))?;
                        Polyline::new(v, false)
                    };
                    pieces.push(place(pl, &xf, tol, false).map_err(|m| e.placed_error(file, m))?);
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
                    if let Some(pl) = poly(vs, e.int(70) & 1 != 0) {
                        pieces.push(
                            place(pl, &xf, tol, opts.fit).map_err(|m| e.placed_error(file, m))?,
                        );
                    }
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
                    // flattened within half the tolerance, fitted within the other half
                    let v = flatten::elliptical_arc(c, major, ratio, t0, t1, ltol / 2.0)
                        .map_err(|err| e.curve_error(file, err, tol))?;
                    let mut pl = Polyline::new(v, false);
                    close_if_full(&mut pl, ltol / 2.0);
                    spend(&mut curve_points, pl.len(), e, file, tol)?;
                    pieces.push(
                        place(pl, &xf, tol / 2.0, opts.fit).map_err(|m| e.placed_error(file, m))?,
                    );
                }
                "SPLINE" => match spline(e, file, ltol / 2.0, tol)? {
                    Some((pl, flattened)) => {
                        spend(&mut curve_points, pl.len(), e, file, tol)?;
                        let fit_tol = if flattened { tol / 2.0 } else { tol };
                        pieces.push(
                            place(pl, &xf, fit_tol, opts.fit)
                                .map_err(|m| e.placed_error(file, m))?,
                        )
                    }
                    None => warnings.push(format!(
                        "{} has inconsistent knots, weights or points and was skipped",
                        e.handle()
                    )),
                },
                "HATCH" => {
                    let h = hatch::read(e, &layer, file, ltol, tol, &mut warnings)?;
                    let mut loops = Vec::with_capacity(h.loops.len());
                    for l in h.loops {
                        spend(&mut curve_points, l.polyline.len(), e, file, tol)?;
                        let fit_tol = if l.flattened { tol / 2.0 } else { tol };
                        loops.push(
                            place(l.polyline, &xf, fit_tol, opts.fit)
                                .map_err(|m| e.placed_error(file, m))?,
                        );
                    }
                    let keep = hatch::keep_by_style(&loops, h.style);
                    hatch_loops.extend(
                        loops
                            .into_iter()
                            .zip(keep)
                            .filter_map(|(l, k)| k.then_some(l)),
                    );
                }
                "SEQEND" | "VERTEX" | "ATTRIB" | "ATTDEF" => {}
                other => *skipped.entry(other.to_string()).or_default() += 1,
            }
        }
    }
    for (kind, n) in skipped {
        warnings.push(format!(
            "{n} {kind} entit{} skipped (no geometry we cut)",
            if n == 1 { "y" } else { "ies" }
        ));
    }
    names.resize(pieces.len(), last_name);
    let read: Vec<(Polyline, String)> = pieces.iter().cloned().zip(names).collect();
    let mut paths = chain(pieces, tol, &mut warnings);
    // a hatch drawn over its own boundary (an associative hatch keeps the polyline or
    // circles it was made from): the loop that repeats a contour adds nothing
    for l in hatch_loops {
        if !paths.iter().any(|p| p.closed && same_loop(p, &l, tol)) {
            paths.push(l);
        }
    }
    let mut drawing = DxfDrawing {
        shape: Shape::new(Vec::new()),
        scale,
        warnings: Vec::new(),
        pieces: read,
    };
    for (i, p) in paths.iter().enumerate() {
        if p.closed {
            for x in self_intersections(p, 3) {
                let at = drawing.entities_at(x, 10.0 * tol, 3);
                warnings.push(format!(
                    "contour {i} crosses itself near ({:.4}, {:.4}){}",
                    x.x,
                    x.y,
                    if at.is_empty() {
                        String::new()
                    } else {
                        format!(": {}", at.join(", "))
                    }
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
    drawing.shape = Shape::new(paths);
    drawing.warnings = warnings;
    Ok(drawing)
}

/// Whether closed paths `a` and `b` trace the same loop within `tol` (bounds, area and
/// length): a hatch's boundary and the entity it was made from.
fn same_loop(a: &Polyline, b: &Polyline, tol: f64) -> bool {
    let (ba, bb) = (a.bounds(), b.bounds());
    ba.min.dist(bb.min) <= 2.0 * tol
        && ba.max.dist(bb.max) <= 2.0 * tol
        && (a.length() - b.length()).abs() <= 4.0 * tol
        && (a.area().abs() - b.area().abs()).abs() <= 2.0 * tol * a.length().max(b.length())
}

/// Blocks nested deeper than this are refused (a block that inserts itself, directly or
/// not, would nest without end).
pub const MAX_NESTING: usize = 64;

/// The most block instances (INSERTs, and every cell of MINSERT arrays) one drawing may
/// place.
pub const MAX_PLACEMENTS: usize = 1_000_000;

/// A block definition: its base point and its entities.
struct Block<'a> {
    base: Point,
    records: Vec<Entity<'a>>,
}

/// Entities to read, where they land in the drawing, the layer an entity on layer 0 takes
/// (the INSERT's), and how deep in blocks they lie.
struct Work<'r, 'a> {
    records: &'r [Entity<'a>],
    xf: Xf,
    layer: Option<String>,
    depth: usize,
}

/// A 2D affine map p ↦ (a x + b y, c x + d y) + t: units, block insertions (base point,
/// scale, rotation, array cell) and mirrored extrusion directions.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Xf {
    a: f64,
    b: f64,
    c: f64,
    d: f64,
    t: Point,
}

impl Xf {
    const MIRROR_X: Xf = Xf {
        a: -1.0,
        b: 0.0,
        c: 0.0,
        d: 1.0,
        t: Point::new(0.0, 0.0),
    };
    fn scale(s: f64) -> Xf {
        Xf {
            a: s,
            b: 0.0,
            c: 0.0,
            d: s,
            t: Point::default(),
        }
    }
    fn apply(&self, p: Point) -> Point {
        Point::new(
            self.a * p.x + self.b * p.y + self.t.x,
            self.c * p.x + self.d * p.y + self.t.y,
        )
    }
    /// This map after `inner`.
    fn then(&self, inner: &Xf) -> Xf {
        Xf {
            a: self.a * inner.a + self.b * inner.c,
            b: self.a * inner.b + self.b * inner.d,
            c: self.c * inner.a + self.d * inner.c,
            d: self.c * inner.b + self.d * inner.d,
            t: self.apply(inner.t),
        }
    }
    fn det(&self) -> f64 {
        self.a * self.d - self.b * self.c
    }
    /// The most a length grows under the map (its largest singular value).
    fn stretch(&self) -> f64 {
        let s = self.a * self.a + self.b * self.b + self.c * self.c + self.d * self.d;
        let det = self.det();
        ((s + (s * s - 4.0 * det * det).max(0.0).sqrt()) / 2.0).sqrt()
    }
    /// Whether the map keeps circles circles (a rotation and a uniform scale, perhaps
    /// mirrored).
    fn is_similarity(&self) -> bool {
        let e = 1e-12 * self.stretch();
        ((self.a - self.d).abs() <= e && (self.b + self.c).abs() <= e)
            || ((self.a + self.d).abs() <= e && (self.b - self.c).abs() <= e)
    }
}

/// A piece in its entity's units placed in the drawing (mm) by `xf`, fitted with lines and
/// arcs within `tol` mm when `fit`. A map that does not keep circles (a block inserted
/// with unequal X and Y scales) turns arcs into ellipses: they are flattened within half
/// of `tol` and fitted within the other half.
fn place(pl: Polyline, xf: &Xf, tol: f64, fit: bool) -> Result<Polyline, String> {
    let fitted = |pl: Polyline, tol: f64| {
        crate::biarc::fit_polyline(&pl, &crate::biarc::BiarcOptions::with_tolerance(tol)).0
    };
    if xf.is_similarity() {
        let flip = xf.det() < 0.0;
        let vs = pl
            .vertices
            .iter()
            .map(|v| {
                let p = xf.apply(v.pos());
                Vertex::new(p.x, p.y, if flip { -v.bulge } else { v.bulge })
            })
            .collect();
        let out = Polyline::new(vs, pl.closed);
        return Ok(if fit { fitted(out, tol) } else { out });
    }
    let has_arcs = pl.vertices.iter().any(|v| v.bulge != 0.0);
    let local = tol / 2.0 / xf.stretch();
    let mut pts: Vec<Point> = Vec::with_capacity(pl.len());
    for s in pl.segments() {
        pts.push(xf.apply(s.start()));
        if let Segment::Arc { radius, .. } = s {
            let step = 2.0 * (1.0 - (local / radius).min(1.0)).acos();
            let k = (s.sweep().abs() / step.max(1e-9)).ceil();
            if k.is_nan() || k > flatten::MAX_POINTS as f64 {
                return Err(format!(
                    "would need more than {} points to stay within {tol} mm of an arc stretched by its block's scales",
                    flatten::MAX_POINTS
                ));
            }
            let k = k as usize;
            for i in 1..k {
                pts.push(xf.apply(s.point_at(i as f64 / k as f64)));
            }
        }
    }
    if !pl.closed {
        if let Some(v) = pl.vertices.last() {
            pts.push(xf.apply(v.pos()));
        }
    }
    let out = Polyline::from_points(&pts, pl.closed);
    Ok(match (fit, has_arcs) {
        (_, true) => fitted(out, tol / 2.0),
        (true, false) => fitted(out, tol),
        (false, false) => out,
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

/// The vertices of an LWPOLYLINE or POLYLINE as a polyline: repeated vertices dropped, a
/// closing vertex that repeats the first dropped; None with fewer than two.
fn poly(mut vs: Vec<Vertex>, closed: bool) -> Option<Polyline> {
    vs.dedup_by(|b, a| a.x == b.x && a.y == b.y);
    if closed && vs.len() > 2 && vs[0].pos() == vs[vs.len() - 1].pos() {
        vs.pop();
    }
    if vs.len() < 2 {
        return None;
    }
    if !closed {
        if let Some(v) = vs.last_mut() {
            v.bulge = 0.0;
        }
    }
    Some(Polyline::new(vs, closed))
}

fn close_if_full(pl: &mut Polyline, tol: f64) {
    let n = pl.len();
    if n > 2 && pl.vertices[0].pos().dist(pl.vertices[n - 1].pos()) <= tol {
        pl.vertices.pop();
        pl.closed = true;
    }
}

/// A SPLINE as a polyline in its own units: the NURBS from its control points flattened
/// within `tol` (true beside it), or its fit points when it has none (false). `tol_mm` is
/// the tolerance in mm, for messages.
fn spline(
    e: &Entity,
    file: &str,
    tol: f64,
    tol_mm: f64,
) -> Result<Option<(Polyline, bool)>, ImportError> {
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
    let flattened = !ctrl.is_empty();
    let pts = if flattened {
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
    Ok(Some((pl, flattened)))
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
