//! Preview drawings: shapes and tool paths as SVG, +Y up, moves coloured by type (rapids dashed), stitch points as dots, the tool's swept width, the start point, arrows of the cut direction, tabs, a scale bar and a legend; every move on the canvas.

use crate::geom::{Bounds, Point, Polyline, Segment, Shape};
use crate::toolpath::{arc_segment, Move, Toolpath, P3};
use std::f64::consts::PI;
use std::fmt::Write;

/// Colours of the preview, one per kind of move.
pub const SHAPE_COLOUR: &str = "#555555";
pub const RAPID_COLOUR: &str = "#d62728";
pub const LINEAR_COLOUR: &str = "#1f77b4";
pub const ARC_COLOUR: &str = "#2ca02c";
pub const PLUNGE_COLOUR: &str = "#9467bd";
pub const STITCH_COLOUR: &str = "#111111";
pub const JUMP_COLOUR: &str = "#ff7f0e";
/// The band the tool sweeps along cutting moves (drawn translucent under them).
pub const SWEPT_COLOUR: &str = "#9ecae1";
/// The scale bar and the legend's text.
pub const TEXT_COLOUR: &str = "#222222";
/// The ring at the point where the first cut starts.
pub const START_COLOUR: &str = "#ffd400";
/// The arrows along the cuts that show which way the tool goes.
pub const DIRECTION_COLOUR: &str = "#222222";
/// Where the tool rides over a tab (a profile's holding bridge).
pub const TAB_COLOUR: &str = "#e377c2";

/// The colours of a job's tools, in the order the tools first appear: every cut of a job of
/// several operations is drawn in its tool's colour (none of them the rapids' red).
pub const TOOL_COLOURS: [&str; 8] = [
    "#1f77b4", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#17becf", "#bcbd22", "#7f7f7f",
];

/// One operation of a job, as the preview colours and names it: the tool path's moves from
/// `first_move` up to the next operation's are cut with tool `tool`, and the legend shows
/// `label` (the caller's words: tool, operation, time) beside the tool's colour.
#[derive(Clone, Debug, PartialEq)]
pub struct LegendOperation {
    pub first_move: usize,
    pub tool: u32,
    /// The tool's diameter, mm: the width of the band its cuts sweep.
    pub diameter: f64,
    pub label: String,
}

/// The colour of tool `tool` in a job whose operations are `ops`.
pub fn tool_colour(ops: &[LegendOperation], tool: u32) -> &'static str {
    let mut seen: Vec<u32> = Vec::new();
    for o in ops {
        if !seen.contains(&o.tool) {
            seen.push(o.tool);
        }
    }
    let k = seen.iter().position(|&t| t == tool).unwrap_or(0);
    TOOL_COLOURS[k % TOOL_COLOURS.len()]
}

/// What a preview shows besides the shape and the moves.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PreviewOptions {
    /// Width of the drawing, pixels; the height follows.
    pub width_px: f64,
    /// A scale bar of a round length in mm, below the drawing.
    pub scale_bar: bool,
    /// A legend of the kinds of line drawn, below the drawing.
    pub legend: bool,
    /// The band the tool sweeps (its diameter wide) under every cutting move below the stock
    /// top, when the tool path names its tool.
    pub swept: bool,
}

impl Default for PreviewOptions {
    fn default() -> Self {
        PreviewOptions {
            width_px: 800.0,
            scale_bar: true,
            legend: true,
            swept: true,
        }
    }
}

/// Draws a shape and/or a tool path `width_px` wide with the default options: see
/// [`svg_with`].
pub fn svg(shape: Option<&Shape>, tp: Option<&Toolpath>, width_px: f64) -> String {
    svg_with(
        shape,
        tp,
        &PreviewOptions {
            width_px,
            ..Default::default()
        },
    )
}

/// Draws a shape and/or a tool path, scaled to fit, +Y up: the shape's outlines grey,
/// cutting lines blue, arcs green, plunges purple dots, rapids red dashed, stitches black
/// dots and jumps orange dashed; under the cuts the band the tool sweeps; below the drawing
/// a scale bar and a legend of what is drawn.
pub fn svg_with(shape: Option<&Shape>, tp: Option<&Toolpath>, o: &PreviewOptions) -> String {
    svg_of_job(shape, tp, &[], o)
}

/// Draws a job of several operations like [`svg_with`], every operation's cuts (lines,
/// arcs, plunges) in its tool's colour ([`tool_colour`]); the legend has a line for each
/// operation, its tool's colour beside its label, in place of the kinds of cut. With no
/// operations it is [`svg_with`].
pub fn svg_of_job(
    shape: Option<&Shape>,
    tp: Option<&Toolpath>,
    ops: &[LegendOperation],
    o: &PreviewOptions,
) -> String {
    let mut b = Bounds::EMPTY;
    if let Some(s) = shape {
        b = b.union(&s.bounds());
    }
    let tool = tp.and_then(|t| t.tool).map_or(0.0, |t| t.diameter);
    let swept = o.swept && tool > 0.0;
    if let Some(t) = tp {
        // every move drawn is on the canvas, rapids above the stock included
        t.walk(P3::default(), |from, m, to| {
            if from.xy().dist(to.xy()) > 1e-9 || !matches!(m, Move::Rapid { .. }) {
                let mut mb = Bounds::EMPTY;
                mb.add_point(from.xy());
                mb.add_point(to.xy());
                if let Move::Arc { center, ccw, .. } = m {
                    mb = mb.union(&arc_segment(from.xy(), to.xy(), *center, *ccw).bounds());
                }
                if swept && matches!(m, Move::Linear { .. } | Move::Arc { .. }) {
                    let r = tool / 2.0;
                    mb.add_point(mb.min - Point::new(r, r));
                    mb.add_point(mb.max + Point::new(r, r));
                }
                b = b.union(&mb);
            }
        });
    }
    if b.is_empty() {
        b.add_point(Point::default());
    }
    let size = b.width().max(b.height()).max(1e-6);
    let margin = size * 0.04;
    let sw = size / 500.0;
    let kinds = tp.map(kinds_drawn).unwrap_or_default();
    let marks = tp.map(|t| marks_of(t, size)).unwrap_or_default();
    // the band below the drawing: a line for the scale bar, then the legend, three to a line
    let line = size / 28.0;
    let mut legend: Vec<(&str, String)> = Vec::new();
    // a job's operations, a line each, before the marks
    let op_rows = if o.legend { ops.len() } else { 0 };
    if o.legend {
        if shape.is_some() {
            legend.push(("outline", "outline".into()));
        }
        if swept && (kinds.linear || kinds.arc) {
            legend.push((
                "swept",
                if ops.is_empty() {
                    format!("tool width ({} mm)", num(tool))
                } else {
                    "tool width".to_string()
                },
            ));
        }
        for (on, key, text) in [
            (marks.start.is_some(), "start", "start"),
            (!marks.arrows.is_empty(), "direction", "cut direction"),
            (!marks.tabs.is_empty(), "tab", "tab"),
            (kinds.linear && ops.is_empty(), "linear", "cut"),
            (kinds.arc && ops.is_empty(), "arc", "arc cut"),
            (kinds.plunge && ops.is_empty(), "plunge", "straight down"),
            (kinds.rapid, "rapid", "rapid"),
            (kinds.stitch, "stitch", "stitch"),
            (kinds.jump, "jump", "jump"),
        ] {
            if on {
                legend.push((key, text.into()));
            }
        }
    }
    let rows = usize::from(o.scale_bar) + op_rows + legend.len().div_ceil(3);
    let band = if rows > 0 {
        line * (rows as f64 + 0.5)
    } else {
        0.0
    };
    let (x0, y0) = (b.min.x - margin, b.min.y - margin - band);
    let (w, h) = (b.width() + 2.0 * margin, b.height() + 2.0 * margin + band);
    let px_w = o.width_px.max(16.0);
    let px_h = (px_w * h / w).clamp(16.0, 20_000.0);
    let mut out = String::new();
    let _ = writeln!(
        out,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{px_w:.0}" height="{px_h:.0}" viewBox="{} {} {} {}">"#,
        f(x0),
        f(-(y0 + h)),
        f(w),
        f(h)
    );
    let _ = writeln!(
        out,
        r#"<rect x="{}" y="{}" width="{}" height="{}" fill="white"/>"#,
        f(x0),
        f(-(y0 + h)),
        f(w),
        f(h)
    );
    // +Y up: everything below is drawn in the shape's own coordinates
    out.push_str("<g transform=\"scale(1,-1)\" fill=\"none\" stroke-linecap=\"round\" stroke-linejoin=\"round\">\n");
    if let (true, Some(t)) = (swept, tp) {
        if ops.is_empty() {
            draw_swept(&mut out, t, tool);
        } else {
            for (part, op) in parts(t, ops) {
                draw_swept(&mut out, &part, op.diameter);
            }
        }
    }
    if let Some(s) = shape {
        for pl in &s.paths {
            let _ = writeln!(
                out,
                r#"<path d="{}" stroke="{SHAPE_COLOUR}" stroke-width="{}"/>"#,
                polyline_d(pl),
                f(sw * 2.0)
            );
        }
    }
    if let Some(t) = tp {
        if ops.is_empty() {
            draw_toolpath(&mut out, t, sw, P3::default(), None);
        } else {
            // each operation's moves in its tool's colour, from where the last one left off
            let mut pos = P3::default();
            for (part, op) in parts(t, ops) {
                pos = draw_toolpath(&mut out, &part, sw, pos, Some(tool_colour(ops, op.tool)));
            }
        }
    }
    draw_marks(&mut out, &marks, sw);
    out.push_str("</g>\n");
    // the band, in the drawing's unflipped frame (y down): world (x, y) is at (x, -y)
    let font = line * 0.6;
    let left = b.min.x;
    let mut row_y = -(b.min.y - margin) + line * 0.9;
    if o.scale_bar {
        let len = round_length(w * 0.2);
        let (xa, xb) = (left, left + len);
        let tick = line * 0.25;
        let _ = writeln!(
            out,
            r#"<path d="M{} {}V{}H{}V{}" fill="none" stroke="{TEXT_COLOUR}" stroke-width="{}"/>"#,
            f(xa),
            f(row_y - tick),
            f(row_y),
            f(xb),
            f(row_y - tick),
            f(sw * 1.5)
        );
        let _ = writeln!(
            out,
            r#"<text x="{}" y="{}" font-family="sans-serif" font-size="{}" fill="{TEXT_COLOUR}">{} mm</text>"#,
            f(xb + line * 0.3),
            f(row_y),
            f(font),
            num(len)
        );
        row_y += line;
    }
    if o.legend {
        for op in ops {
            let ym = row_y - font * 0.35;
            let _ = writeln!(
                out,
                r#"<path d="M{} {}H{}" fill="none" stroke="{}" stroke-width="{}"/>"#,
                f(left),
                f(ym),
                f(left + line * 1.2),
                tool_colour(ops, op.tool),
                f(sw * 4.0)
            );
            let _ = writeln!(
                out,
                r#"<text x="{}" y="{}" font-family="sans-serif" font-size="{}" fill="{TEXT_COLOUR}">{}</text>"#,
                f(left + line * 1.5),
                f(row_y),
                f(font),
                xml_text(&op.label)
            );
            row_y += line;
        }
    }
    let col = w / 3.0;
    for (k, (key, text)) in legend.iter().enumerate() {
        let x = left + col * (k % 3) as f64;
        let y = row_y + line * (k / 3) as f64;
        let sample = line * 1.2;
        let dash = format!("{} {}", f(sw * 6.0), f(sw * 4.0));
        let mark = match *key {
            "outline" => format!(r#"stroke="{SHAPE_COLOUR}" stroke-width="{}""#, f(sw * 2.0)),
            "swept" => format!(
                r#"stroke="{SWEPT_COLOUR}" stroke-width="{}" stroke-opacity="0.45""#,
                f(font * 0.8)
            ),
            "linear" => format!(r#"stroke="{LINEAR_COLOUR}" stroke-width="{}""#, f(sw * 2.0)),
            "tab" => format!(r#"stroke="{TAB_COLOUR}" stroke-width="{}""#, f(sw * 6.0)),
            "arc" => format!(r#"stroke="{ARC_COLOUR}" stroke-width="{}""#, f(sw * 2.0)),
            "rapid" => format!(
                r#"stroke="{RAPID_COLOUR}" stroke-width="{}" stroke-dasharray="{dash}""#,
                f(sw * 2.0)
            ),
            "jump" => format!(
                r#"stroke="{JUMP_COLOUR}" stroke-width="{}" stroke-dasharray="{dash}""#,
                f(sw * 2.0)
            ),
            _ => String::new(),
        };
        let ym = y - font * 0.35;
        match *key {
            "start" => {
                let _ = writeln!(
                    out,
                    r#"<circle cx="{}" cy="{}" r="{}" fill="{START_COLOUR}" stroke="{TEXT_COLOUR}" stroke-width="{}"/>"#,
                    f(x + sample / 2.0),
                    f(ym),
                    f(sw * 7.0),
                    f(sw * 1.5)
                );
            }
            "direction" => {
                // the legend's frame is y down: the arrow points right
                let _ = writeln!(
                    out,
                    r#"<path d="M{} {}L{} {}L{} {}Z" fill="{DIRECTION_COLOUR}"/>"#,
                    f(x + sample * 0.75),
                    f(ym),
                    f(x + sample * 0.25),
                    f(ym - sw * 5.0),
                    f(x + sample * 0.25),
                    f(ym + sw * 5.0)
                );
            }
            "plunge" | "stitch" => {
                let c = if *key == "plunge" {
                    PLUNGE_COLOUR
                } else {
                    STITCH_COLOUR
                };
                let _ = writeln!(
                    out,
                    r#"<circle cx="{}" cy="{}" r="{}" fill="{c}"/>"#,
                    f(x + sample / 2.0),
                    f(ym),
                    f(sw * 3.0)
                );
            }
            _ => {
                let _ = writeln!(
                    out,
                    r#"<path d="M{} {}H{}" fill="none" {mark}/>"#,
                    f(x),
                    f(ym),
                    f(x + sample)
                );
            }
        }
        let _ = writeln!(
            out,
            r#"<text x="{}" y="{}" font-family="sans-serif" font-size="{}" fill="{TEXT_COLOUR}">{text}</text>"#,
            f(x + sample + line * 0.3),
            f(y),
            f(font)
        );
    }
    out.push_str("</svg>\n");
    out
}

/// What a tool path shows beyond its moves: where the first cut starts, arrows along the cuts
/// (a point and a unit direction each), and the pieces where the tool rides over a tab.
#[derive(Clone, Debug, Default)]
struct Marks {
    start: Option<Point>,
    arrows: Vec<(Point, Point)>,
    tabs: Vec<Segment>,
}

/// The most arrows of cut direction a drawing carries.
const MAX_ARROWS: usize = 24;

/// The marks of a tool path drawn `size` mm across. A tab is a cut that follows a straight
/// rise at feed (the same XY, higher Z) below the stock top and stays above the depth the
/// tool rose from, until the tool is back down there.
fn marks_of(t: &Toolpath, size: f64) -> Marks {
    let mut m = Marks::default();
    let mut cuts: Vec<Segment> = Vec::new();
    let mut rose_from: Option<f64> = None;
    t.walk(P3::default(), |from, mv, to| {
        let (a, b) = (from.xy(), to.xy());
        let same_xy = a.dist(b) < 1e-9;
        let piece = match mv {
            Move::Linear { .. } | Move::Stitch { .. } if !same_xy => Some(Segment::Line { a, b }),
            Move::Arc { center, ccw, .. } => Some(arc_segment(a, b, *center, *ccw)),
            _ => None,
        };
        if m.start.is_none()
            && matches!(
                mv,
                Move::Linear { .. } | Move::Arc { .. } | Move::Stitch { .. }
            )
        {
            m.start = Some(a);
        }
        match mv {
            Move::Rapid { .. } => rose_from = None,
            Move::Linear { .. } if same_xy && to.z > from.z + 1e-9 && from.z < 0.0 => {
                rose_from = Some(rose_from.map_or(from.z, |z: f64| z.min(from.z)));
            }
            _ => {}
        }
        if let Some(p) = piece {
            if let Some(depth) = rose_from {
                if from.z.max(to.z) > depth + 1e-9 {
                    m.tabs.push(p);
                }
                if to.z <= depth + 1e-9 {
                    rose_from = None;
                }
            }
            cuts.push(p);
        } else if rose_from.is_some_and(|d| same_xy && to.z <= d + 1e-9) {
            rose_from = None;
        }
    });
    m.arrows = arrows_along(&cuts, size);
    m
}

/// Arrows of direction along a run of cuts in a drawing `size` across: at most
/// [`MAX_ARROWS`], evenly spaced by length, each a point and a unit direction.
pub(crate) fn arrows_along(cuts: &[Segment], size: f64) -> Vec<(Point, Point)> {
    let mut arrows = Vec::new();
    let total: f64 = cuts.iter().map(|c| c.length()).sum();
    if total <= 1e-9 {
        return arrows;
    }
    let spacing = (total / MAX_ARROWS as f64).max(size / 30.0);
    let mut next = spacing * 0.5;
    let mut at = 0.0;
    for c in cuts {
        let len = c.length();
        while next <= at + len && arrows.len() < MAX_ARROWS {
            let k = ((next - at) / len).clamp(0.0, 1.0);
            let (p0, p1) = (
                c.point_at((k - 1e-3).max(0.0)),
                c.point_at((k + 1e-3).min(1.0)),
            );
            let d = p1 - p0;
            let l = d.x.hypot(d.y);
            if l > 1e-12 {
                arrows.push((c.point_at(k), Point::new(d.x / l, d.y / l)));
            }
            next += spacing;
        }
        at += len;
    }
    arrows
}

/// A filled arrowhead of half-width `s` at `p` pointing along the unit `d`, as SVG path data.
pub(crate) fn arrow_d(p: Point, d: Point, s: f64) -> String {
    let n = Point::new(-d.y, d.x);
    let tip = p + Point::new(d.x * s, d.y * s);
    let back = p - Point::new(d.x * s * 0.8, d.y * s * 0.8);
    let (l, r) = (
        back + Point::new(n.x * s, n.y * s),
        back - Point::new(n.x * s, n.y * s),
    );
    format!(
        "M{} {}L{} {}L{} {}Z",
        f(tip.x),
        f(tip.y),
        f(l.x),
        f(l.y),
        f(r.x),
        f(r.y)
    )
}

/// A round length near `l` for a scale bar (1, 2 or 5 times a power of ten).
pub(crate) fn scale_length(l: f64) -> f64 {
    round_length(l)
}

/// A length for a label, in few digits.
pub(crate) fn label_number(v: f64) -> String {
    num(v)
}

/// Draws the tabs, the start ring and the arrows (in the flipped, y-up group).
fn draw_marks(out: &mut String, m: &Marks, sw: f64) {
    for tab in &m.tabs {
        let a = tab.start();
        let _ = writeln!(
            out,
            r#"<path d="M{} {}{}" stroke="{TAB_COLOUR}" stroke-width="{}" stroke-linecap="butt"/>"#,
            f(a.x),
            f(a.y),
            arc_d(tab),
            f(sw * 6.0)
        );
    }
    let s = sw * 5.0;
    for (p, d) in &m.arrows {
        let _ = writeln!(
            out,
            r#"<path d="{}" fill="{DIRECTION_COLOUR}" stroke="none"/>"#,
            arrow_d(*p, *d, s)
        );
    }
    if let Some(p) = m.start {
        let _ = writeln!(
            out,
            r#"<circle cx="{}" cy="{}" r="{}" fill="{START_COLOUR}" stroke="{TEXT_COLOUR}" stroke-width="{}"/>"#,
            f(p.x),
            f(p.y),
            f(sw * 7.0),
            f(sw * 1.5)
        );
    }
}

/// Which kinds of move a tool path draws.
#[derive(Clone, Copy, Debug, Default)]
struct Kinds {
    linear: bool,
    arc: bool,
    plunge: bool,
    rapid: bool,
    stitch: bool,
    jump: bool,
}

fn kinds_drawn(t: &Toolpath) -> Kinds {
    let mut k = Kinds::default();
    t.walk(P3::default(), |from, m, to| {
        let same_xy = from.xy().dist(to.xy()) < 1e-9;
        match m {
            Move::Rapid { .. } if !same_xy => k.rapid = true,
            Move::Linear { .. } if same_xy && to.z < from.z => k.plunge = true,
            Move::Linear { .. } if !same_xy => k.linear = true,
            Move::Arc { .. } => k.arc = true,
            Move::Stitch { .. } => k.stitch = true,
            Move::Jump { .. } if !same_xy => k.jump = true,
            _ => {}
        }
    });
    k
}

/// The band the tool (of diameter `tool`) sweeps along every cutting move below the stock
/// top, in one translucent group so overlaps do not darken.
fn draw_swept(out: &mut String, t: &Toolpath, tool: f64) {
    let _ = writeln!(
        out,
        r#"<g opacity="0.45" stroke="{SWEPT_COLOUR}" stroke-width="{}">"#,
        f(tool)
    );
    t.walk(P3::default(), |from, m, to| {
        if from.z >= 0.0 && to.z >= 0.0 {
            return;
        }
        let (a, b) = (from.xy(), to.xy());
        match m {
            Move::Linear { .. } if a.dist(b) >= 1e-9 => {
                let _ = writeln!(
                    out,
                    r#"<path d="M{} {}L{} {}"/>"#,
                    f(a.x),
                    f(a.y),
                    f(b.x),
                    f(b.y)
                );
            }
            Move::Arc { center, ccw, .. } => {
                let seg = arc_segment(a, b, *center, *ccw);
                let _ = writeln!(out, r#"<path d="M{} {}{}"/>"#, f(a.x), f(a.y), arc_d(&seg));
            }
            _ => {}
        }
    });
    out.push_str("</g>\n");
}

/// A round length near `l`: 1, 2 or 5 times a power of ten.
fn round_length(l: f64) -> f64 {
    let l = l.max(1e-9);
    let p = 10f64.powf(l.log10().floor());
    [5.0, 2.0, 1.0]
        .into_iter()
        .map(|k| k * p)
        .find(|&v| v <= l)
        .unwrap_or(p)
}

/// A length for a label: few digits.
fn num(v: f64) -> String {
    let s = format!("{v:.6}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    s.to_string()
}

/// The job's tool path cut into its operations' parts, each with its operation; each part
/// starts with a rapid to where the last one ended, so it can be walked on its own. Moves
/// before the first operation go with it.
fn parts<'a>(t: &Toolpath, ops: &'a [LegendOperation]) -> Vec<(Toolpath, &'a LegendOperation)> {
    let mut out = Vec::new();
    let mut pos: Option<P3> = None;
    for (k, op) in ops.iter().enumerate() {
        let from = if k == 0 {
            0
        } else {
            op.first_move.min(t.moves.len())
        };
        let to = ops
            .get(k + 1)
            .map_or(t.moves.len(), |n| n.first_move.min(t.moves.len()))
            .max(from);
        let mut part = Toolpath::new("");
        if let Some(p) = pos {
            // the tool is already there: a rapid of no length, drawn as nothing
            part.moves.push(Move::Rapid { to: p });
        }
        part.moves.extend_from_slice(&t.moves[from..to]);
        pos = Some(part.walk(pos.unwrap_or_default(), |_, _, _| {}));
        out.push((part, op));
    }
    out
}

/// Text for an SVG element: `&`, `<` and `>` escaped.
fn xml_text(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

/// Draws the moves of `t` from `start`, cuts (lines, arcs, plunges) in `cut_colour` when
/// given, else each kind in its own colour; returns where the tool ends.
fn draw_toolpath(
    out: &mut String,
    t: &Toolpath,
    sw: f64,
    start: P3,
    cut_colour: Option<&str>,
) -> P3 {
    let dash = format!("{} {}", f(sw * 6.0), f(sw * 4.0));
    let linear = cut_colour.unwrap_or(LINEAR_COLOUR);
    let arc = cut_colour.unwrap_or(ARC_COLOUR);
    let plunge = cut_colour.unwrap_or(PLUNGE_COLOUR);
    t.walk(start, |from, m, to| {
        let (a, b) = (from.xy(), to.xy());
        let same_xy = a.dist(b) < 1e-9;
        match m {
            Move::Rapid { .. } if !same_xy => {
                let _ = writeln!(
                    out,
                    r#"<path d="M{} {}L{} {}" stroke="{RAPID_COLOUR}" stroke-width="{}" stroke-dasharray="{dash}"/>"#,
                    f(a.x), f(a.y), f(b.x), f(b.y), f(sw)
                );
            }
            Move::Linear { .. } if same_xy && to.z < from.z => {
                let _ = writeln!(
                    out,
                    r#"<circle cx="{}" cy="{}" r="{}" fill="{plunge}"/>"#,
                    f(b.x),
                    f(b.y),
                    f(sw * 2.5)
                );
            }
            Move::Linear { .. } if same_xy => {}
            Move::Linear { .. } => {
                let _ = writeln!(
                    out,
                    r#"<path d="M{} {}L{} {}" stroke="{linear}" stroke-width="{}"/>"#,
                    f(a.x), f(a.y), f(b.x), f(b.y), f(sw)
                );
            }
            Move::Arc { center, ccw, .. } => {
                let seg = arc_segment(a, b, *center, *ccw);
                let _ = writeln!(
                    out,
                    r#"<path d="M{} {}{}" stroke="{arc}" stroke-width="{}"/>"#,
                    f(a.x), f(a.y), arc_d(&seg), f(sw)
                );
            }
            Move::Stitch { .. } => {
                let _ = writeln!(
                    out,
                    r#"<path d="M{} {}L{} {}" stroke="{STITCH_COLOUR}" stroke-width="{}"/><circle cx="{}" cy="{}" r="{}" fill="{STITCH_COLOUR}"/>"#,
                    f(a.x), f(a.y), f(b.x), f(b.y), f(sw * 0.6), f(b.x), f(b.y), f(sw * 2.0)
                );
            }
            Move::Jump { .. } if !same_xy => {
                let _ = writeln!(
                    out,
                    r#"<path d="M{} {}L{} {}" stroke="{JUMP_COLOUR}" stroke-width="{}" stroke-dasharray="{dash}"/>"#,
                    f(a.x), f(a.y), f(b.x), f(b.y), f(sw)
                );
            }
            _ => {}
        }
    })
}

/// A number for SVG: short, finite.
fn f(v: f64) -> String {
    if v.is_finite() {
        let s = format!("{v:.4}");
        let s = s.trim_end_matches('0').trim_end_matches('.');
        if s == "-0" {
            "0".into()
        } else {
            s.to_string()
        }
    } else {
        "0".into()
    }
}

/// The SVG arc command(s) from the segment's start to its end (split in two past a half turn).
fn arc_d(s: &Segment) -> String {
    let Segment::Arc { radius, ccw, .. } = *s else {
        let e = s.end();
        return format!("L{} {}", f(e.x), f(e.y));
    };
    let sweep = s.sweep();
    // in the flipped group the local frame is y-up, where sweep-flag 1 turns counter-clockwise
    let flag = if ccw { 1 } else { 0 };
    let mut d = String::new();
    let parts = if sweep.abs() > PI * 0.999 { 2 } else { 1 };
    for k in 1..=parts {
        let p = s.point_at(k as f64 / parts as f64);
        let _ = write!(
            d,
            "A{} {} 0 0 {flag} {} {}",
            f(radius),
            f(radius),
            f(p.x),
            f(p.y)
        );
    }
    d
}

/// The SVG path data of a polyline (bulge arcs as arcs).
pub fn polyline_d(pl: &Polyline) -> String {
    let mut d = String::new();
    if let Some(v) = pl.vertices.first() {
        let _ = write!(d, "M{} {}", f(v.x), f(v.y));
    }
    for s in pl.segments() {
        d.push_str(&arc_d(&s));
    }
    if pl.closed {
        d.push('Z');
    }
    d
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// The four numbers of an SVG's viewBox (min x, min y, width, height).
    pub(crate) fn view_box(svg: &str) -> Vec<f64> {
        svg.split("viewBox=\"")
            .nth(1)
            .unwrap()
            .split('"')
            .next()
            .unwrap()
            .split(' ')
            .map(|v| v.parse().unwrap())
            .collect()
    }

    #[test]
    fn the_drawing_parses_as_svg_and_flips_y() {
        let shape = Shape::new(vec![Polyline::circle(Point::new(10.0, 5.0), 4.0)]);
        let mut tp = Toolpath::new("t");
        tp.push(Move::Rapid {
            to: P3::new(14.0, 5.0, 5.0),
        });
        tp.push(Move::Linear {
            to: P3::new(14.0, 5.0, -1.0),
            feed: 100.0,
        });
        tp.push(Move::Arc {
            to: P3::new(6.0, 5.0, -1.0),
            center: Point::new(10.0, 5.0),
            ccw: true,
            feed: 100.0,
        });
        let s = svg(Some(&shape), Some(&tp), 400.0);
        // usvg reads it back; the arc ccw from (14,5) to (6,5) passes over the top (y = 9)
        let tree = usvg::Tree::from_str(&s, &usvg::Options::default()).unwrap();
        let bb = tree.root().abs_bounding_box();
        assert!(bb.width() > 0.0);
        assert!(s.contains(ARC_COLOUR) && s.contains(PLUNGE_COLOUR));
        // the ccw arc is drawn with sweep flag 1 in the y-up group
        assert!(s.contains("A4 4 0 0 1 10 9"), "{s}");
    }

    #[test]
    fn a_plan_shows_its_swept_width_a_scale_bar_and_a_legend_of_what_is_drawn() {
        let mut tp = Toolpath::new("t");
        tp.tool = Some(crate::toolpath::Tool::flat(6.0));
        tp.push(Move::Rapid {
            to: P3::new(0.0, 0.0, 5.0),
        });
        tp.push(Move::Linear {
            to: P3::new(0.0, 0.0, -1.0),
            feed: 100.0,
        });
        tp.push(Move::Linear {
            to: P3::new(80.0, 0.0, -1.0),
            feed: 100.0,
        });
        let s = svg(None, Some(&tp), 400.0);
        usvg::Tree::from_str(&s, &usvg::Options::default()).unwrap();
        // the swept band is the tool's diameter wide
        assert!(
            s.contains(SWEPT_COLOUR) && s.contains(r#"stroke-width="6""#),
            "{s}"
        );
        // a scale bar of a round length: the drawing is about 93 mm wide, a fifth is 18.6
        assert!(s.contains(">10 mm</text>"), "{s}");
        assert!(s.contains(">tool width (6 mm)</text>") && s.contains(">cut</text>"));
        assert!(s.contains(">straight down</text>"));
        assert!(
            !s.contains(">arc cut</text>"),
            "no arc drawn, none in the legend"
        );
        // a shape alone: an outline in the legend, nothing of a tool path
        let shape = Shape::new(vec![Polyline::circle(Point::new(0.0, 0.0), 10.0)]);
        let s = svg(Some(&shape), None, 400.0);
        assert!(
            s.contains(">outline</text>") && !s.contains(LINEAR_COLOUR),
            "{s}"
        );
        assert!(!s.contains("stroke-dasharray"));
        let bare = svg_with(
            Some(&shape),
            None,
            &PreviewOptions {
                scale_bar: false,
                legend: false,
                ..Default::default()
            },
        );
        assert!(!bare.contains("<text"));
    }

    /// The numbers of an SVG attribute `name="…"` of every element that has it.
    fn attr(s: &str, name: &str) -> Vec<f64> {
        s.split(&format!(" {name}=\""))
            .skip(1)
            .filter_map(|r| r.split('"').next()?.parse().ok())
            .collect()
    }

    #[test]
    fn a_profile_with_tabs_shows_its_start_its_direction_and_its_tabs_all_on_the_canvas() {
        let square = Polyline::new(
            [(0.0, 0.0), (60.0, 0.0), (60.0, 40.0), (0.0, 40.0)]
                .iter()
                .map(|&(x, y)| crate::geom::Vertex::new(x, y, 0.0))
                .collect(),
            true,
        );
        let shape = Shape::new(vec![square]);
        let mut p = crate::ops::ProfileParams {
            tabs: 4,
            tab_width: 4.0,
            tab_height: 1.0,
            ..Default::default()
        };
        p.cut.depth = 3.0;
        p.cut.stepdown = 1.5;
        let tp = crate::ops::profile(&shape, &p).unwrap();
        let marks = marks_of(&tp, 70.0);
        // four tabs on the last pass, each piece above the pass's depth
        assert!(marks.tabs.len() >= 4, "{} tab pieces", marks.tabs.len());
        let tab_len: f64 = marks.tabs.iter().map(|t| t.length()).sum();
        // each tab: its width plus the tool's (3 mm) at least, with the ramp back down after
        // it; far less than the last pass's loop (about 209 mm)
        assert!(
            (4.0 * (4.0 + 3.0) - 1e-6..0.6 * 209.0).contains(&tab_len),
            "{tab_len}"
        );
        // the start is where the first cut begins, and arrows follow the cuts' direction
        let mut first = None;
        tp.walk(P3::default(), |from, m, _| {
            if first.is_none() && matches!(m, Move::Linear { .. } | Move::Arc { .. }) {
                first = Some(from.xy());
            }
        });
        assert_eq!(marks.start, first);
        assert!(marks.arrows.len() >= 8 && marks.arrows.len() <= MAX_ARROWS);
        // the loop goes one way round (only a ramp entry goes back and forth): the arrows'
        // turn about the centre has one sign, but for the ramp's
        let c = Point::new(30.0, 20.0);
        let turns: Vec<f64> = marks
            .arrows
            .iter()
            .map(|(q, d)| (q.x - c.x) * d.y - (q.y - c.y) * d.x)
            .collect();
        let one_way = turns.iter().filter(|t| **t < 0.0).count();
        let most = one_way.max(turns.len() - one_way);
        assert!(most * 4 >= turns.len() * 3, "{turns:?}");
        let s = svg(Some(&shape), Some(&tp), 600.0);
        assert!(s.contains(TAB_COLOUR) && s.contains(START_COLOUR));
        assert!(
            s.contains(">start</text>")
                && s.contains(">cut direction</text>")
                && s.contains(">tab</text>")
        );
        // every move's ends inside the viewBox (y is flipped: the box holds -y)
        let vb = view_box(&s);
        tp.walk(P3::default(), |from, _, to| {
            for q in [from.xy(), to.xy()] {
                assert!(q.x >= vb[0] && q.x <= vb[0] + vb[2], "{q:?} off {vb:?}");
                assert!(-q.y >= vb[1] && -q.y <= vb[1] + vb[3], "{q:?} off {vb:?}");
            }
        });
        assert!(!attr(&s, "cx").is_empty());
    }

    #[test]
    fn scale_bars_are_round_lengths() {
        assert_eq!(round_length(18.6), 10.0);
        assert_eq!(round_length(23.0), 20.0);
        assert_eq!(round_length(0.07), 0.05);
        assert_eq!(round_length(5000.0), 5000.0);
    }
}
