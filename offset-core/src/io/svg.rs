//! SVG import (via usvg): paths and basic shapes with their transforms, in mm from the document's size and viewBox, +Y up.
//!
//! usvg resolves styles, `use`, transforms and the viewBox, and turns basic shapes and
//! elliptical arcs into cubic Béziers; we flatten the curves within half the tolerance and
//! fit the points with biarcs within the other half, so a circle in the file comes back as
//! arcs; runs of three or more straight segments (dense polygons and polylines) are fitted
//! within the tolerance. Lengths: usvg works in CSS pixels (96 per inch), so a document with
//! `width="100mm"` is 100 mm wide here. Y is flipped about the document's height.
//! Subpaths that end where they start are closed; open subpaths, crossings and gaps are
//! warnings, as in the DXF reader. Text and images are skipped.
//!
//! Layers: an SVG has groups (`<g>`), and Inkscape's layers are groups with an
//! `inkscape:label`. [`read_layers`] reads only the paths under groups whose `id` or
//! `inkscape:label` is one of the names given (case-insensitive), at any depth; [`layers`]
//! lists the names a file has, for a recipe's globs to match.

use super::chain::{chain, self_intersections};
use super::ImportError;
use crate::biarc::{fit_points, BiarcOptions};
use crate::flatten;
use crate::geom::{Point, Polyline, Shape, Vertex};

/// mm per CSS pixel.
const MM_PER_PX: f64 = 25.4 / 96.0;

/// A drawing read from SVG, with what the reader noticed.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SvgDrawing {
    pub shape: Shape,
    pub warnings: Vec<String>,
}

/// Reads an SVG file with a tolerance of 0.001 mm.
pub fn read(bytes: &[u8], file: &str) -> Result<Shape, ImportError> {
    read_with(bytes, file, 1e-3).map(|d| d.shape)
}

/// Reads an SVG file; curves are approximated within `tolerance` mm.
pub fn read_with(bytes: &[u8], file: &str, tolerance: f64) -> Result<SvgDrawing, ImportError> {
    read_layers(bytes, file, tolerance, &[])
}

/// The Inkscape namespace, whose `label` attribute names a layer.
const INKSCAPE: &str = "http://www.inkscape.org/namespaces/inkscape";

/// The names of the file's groups, in document order, each once (case-insensitive): each
/// group's `inkscape:label` (an Inkscape layer's name) and its `id`.
pub fn layers(bytes: &[u8], file: &str) -> Result<Vec<String>, ImportError> {
    let tree = usvg::Tree::from_data(bytes, &usvg::Options::default())
        .map_err(|e| ImportError::invalid(file, format!("not a readable SVG document: {e}")))?;
    let labels = raw_xml(bytes).labels;
    let mut out: Vec<String> = Vec::new();
    let mut todo: Vec<&usvg::Group> = vec![tree.root()];
    while let Some(g) = todo.pop() {
        for name in group_names(g, &labels) {
            if !out.iter().any(|o| o.eq_ignore_ascii_case(&name)) {
                out.push(name);
            }
        }
        // children pushed in reverse, so they are named in document order
        for node in g.children().iter().rev() {
            if let usvg::Node::Group(c) = node {
                todo.push(c);
            }
        }
    }
    Ok(out)
}

/// Every path of the file, in document order, as messages name it (see [`placed_paths`]),
/// with the names of the groups it lies in (labels and ids, outermost first).
pub fn paths_in_groups(
    bytes: &[u8],
    file: &str,
) -> Result<Vec<(String, Vec<String>)>, ImportError> {
    Ok(placed_paths(bytes, file, 1e-3)?
        .into_iter()
        .map(|p| (p.name, p.groups))
        .collect())
}

/// One drawn element of an SVG file (a `<path>`, `<circle>`, `<rect>`, … as usvg hands it
/// over), where it lies and what it draws.
#[derive(Clone, Debug, PartialEq)]
pub struct PlacedPath {
    /// The element as messages name it: its kind and id (`circle "h5"`), or, without an id,
    /// its kind and place among the file's elements of that kind (`circle #3`, the third
    /// `<circle>`; `path #4` when the file's elements cannot be matched to what usvg drew,
    /// as with `<use>`).
    pub name: String,
    /// The groups it lies in (labels and ids, outermost first).
    pub groups: Vec<String>,
    /// Its subpaths in mm, +Y up, curves within `tolerance` (before the reader chains the
    /// file's pieces into contours).
    pub paths: Vec<Polyline>,
}

/// What usvg does not keep of the raw XML, read in one parse: the `inkscape:label` of every
/// group with an `id` that has one (an Inkscape layer's name), and the drawing elements in
/// document order, each with its tag and id (outside `<defs>` and the other containers that
/// draw nothing by themselves). Both empty when the bytes are not plain XML (compressed
/// SVG), where only ids name groups and elements are named by place.
#[derive(Default)]
struct RawXml {
    labels: Vec<(String, String)>,
    shapes: Vec<(String, String)>,
}

fn raw_xml(bytes: &[u8]) -> RawXml {
    const SHAPES: [&str; 7] = [
        "path", "rect", "circle", "ellipse", "line", "polyline", "polygon",
    ];
    const HIDDEN: [&str; 7] = [
        "defs", "symbol", "clipPath", "mask", "marker", "pattern", "metadata",
    ];
    let Ok(text) = std::str::from_utf8(bytes) else {
        return RawXml::default();
    };
    let opt = usvg::roxmltree::ParsingOptions {
        allow_dtd: true,
        ..Default::default()
    };
    let Ok(doc) = usvg::roxmltree::Document::parse_with_options(text, opt) else {
        return RawXml::default();
    };
    let labels = doc
        .descendants()
        .filter(|n| n.has_tag_name("g"))
        .filter_map(|n| {
            let id = n.attribute("id")?;
            let label = n.attribute((INKSCAPE, "label"))?;
            Some((id.to_string(), label.to_string()))
        })
        .collect();
    let shapes = doc
        .descendants()
        .filter(|n| n.is_element() && SHAPES.contains(&n.tag_name().name()))
        .filter(|n| {
            !n.ancestors()
                .any(|a| a.is_element() && HIDDEN.contains(&a.tag_name().name()))
        })
        .map(|n| {
            (
                n.tag_name().name().to_string(),
                n.attribute("id").unwrap_or_default().to_string(),
            )
        })
        .collect();
    RawXml { labels, shapes }
}

/// Every drawn element of the file, in document order: its name, groups and geometry
/// ([`PlacedPath`]).
pub fn placed_paths(
    bytes: &[u8],
    file: &str,
    tolerance: f64,
) -> Result<Vec<PlacedPath>, ImportError> {
    let tol = if tolerance.is_finite() && tolerance > 0.0 {
        tolerance
    } else {
        1e-3
    };
    let tree = usvg::Tree::from_data(bytes, &usvg::Options::default())
        .map_err(|e| ImportError::invalid(file, format!("not a readable SVG document: {e}")))?;
    let height = tree.size().height() as f64;
    let RawXml {
        labels,
        shapes: elements,
    } = raw_xml(bytes);
    let mut found: Vec<(String, Vec<String>, Vec<Polyline>)> = Vec::new();
    let mut flattened = 0;
    // depth first in document order: a stack of the groups entered, each with the rest of
    // its children and its names
    let root = tree.root();
    let mut stack = vec![(root.children().iter(), group_names(root, &labels))];
    while let Some((children, names)) = stack.last_mut() {
        let Some(node) = children.next() else {
            stack.pop();
            continue;
        };
        match node {
            usvg::Node::Group(c) => {
                let mut inner = names.clone();
                inner.extend(group_names(c, &labels));
                stack.push((c.children().iter(), inner));
            }
            usvg::Node::Path(p) => {
                let mut paths = Vec::new();
                path(p, height, tol, &mut flattened, &mut paths).map_err(|what| {
                    ImportError::invalid(file, format!("path \"{}\" {what}", p.id()))
                })?;
                found.push((p.id().to_string(), names.clone(), paths));
            }
            _ => {}
        }
    }
    // the elements usvg drew, matched to the file's by place when they are as many
    let by_place = elements.len() == found.len()
        && elements
            .iter()
            .zip(&found)
            .all(|((_, id), (drawn, _, _))| id.is_empty() || id == drawn);
    let mut out = Vec::with_capacity(found.len());
    for (k, (id, groups, paths)) in found.into_iter().enumerate() {
        let name = if by_place {
            let (kind, _) = &elements[k];
            if id.is_empty() {
                let nth = elements[..=k].iter().filter(|(t, _)| t == kind).count();
                format!("{kind} #{nth}")
            } else {
                format!("{kind} \"{id}\"")
            }
        } else if id.is_empty() {
            format!("path #{}", k + 1)
        } else {
            let kind = elements
                .iter()
                .find(|(_, i)| *i == id)
                .map_or("path", |(t, _)| t.as_str());
            format!("{kind} \"{id}\"")
        };
        out.push(PlacedPath {
            name,
            groups,
            paths,
        });
    }
    Ok(out)
}

/// A group's names: its label (when Inkscape gave it one) and its id.
fn group_names(g: &usvg::Group, labels: &[(String, String)]) -> Vec<String> {
    let mut names = Vec::new();
    if g.id().is_empty() {
        return names;
    }
    if let Some((_, l)) = labels.iter().find(|(id, _)| id == g.id()) {
        names.push(l.clone());
    }
    names.push(g.id().to_string());
    names
}

/// Reads an SVG file like [`read_with`], only the paths under the groups named `layers`
/// (by `id` or `inkscape:label`, case-insensitive; all paths when empty). Naming layers
/// none of which holds a path is an error that lists the file's group names.
pub fn read_layers(
    bytes: &[u8],
    file: &str,
    tolerance: f64,
    layers: &[String],
) -> Result<SvgDrawing, ImportError> {
    let tol = if tolerance.is_finite() && tolerance > 0.0 {
        tolerance
    } else {
        1e-3
    };
    let opt = usvg::Options::default();
    let tree = usvg::Tree::from_data(bytes, &opt)
        .map_err(|e| ImportError::invalid(file, format!("not a readable SVG document: {e}")))?;
    let height = tree.size().height() as f64;
    let mut pieces = Vec::new();
    let mut warnings = Vec::new();
    let mut flattened = 0;
    let select = Select {
        layers,
        labels: if layers.is_empty() {
            Vec::new()
        } else {
            raw_xml(bytes).labels
        },
    };
    collect(
        tree.root(),
        height,
        tol,
        &select,
        &mut flattened,
        &mut pieces,
        &mut warnings,
    )
    .map_err(|m| ImportError::invalid(file, m))?;
    if !layers.is_empty() && pieces.is_empty() {
        let have = self::layers(bytes, file)?;
        return Err(ImportError::invalid(
            file,
            format!(
                "no geometry in layer(s) or group(s) {} (the file's groups: {})",
                layers.join(", "),
                if have.is_empty() {
                    "none".to_string()
                } else {
                    have.join(", ")
                }
            ),
        ));
    }
    let paths = chain(pieces, tol, &mut warnings);
    for (i, p) in paths.iter().enumerate() {
        if p.closed {
            for x in self_intersections(p, 3) {
                warnings.push(format!(
                    "contour {i} crosses itself near ({:.4}, {:.4}) mm",
                    x.x, x.y
                ));
            }
        }
    }
    Ok(SvgDrawing {
        shape: Shape::new(paths),
        warnings,
    })
}

/// Which groups' paths are read: those named `layers` (all when empty), with the file's
/// Inkscape labels.
struct Select<'a> {
    layers: &'a [String],
    labels: Vec<(String, String)>,
}

impl Select<'_> {
    fn takes(&self, g: &usvg::Group) -> bool {
        group_names(g, &self.labels)
            .iter()
            .any(|n| self.layers.iter().any(|l| l.eq_ignore_ascii_case(n)))
    }
}

/// The paths under `g` (those of the selected groups) as polylines in mm; `flattened`
/// counts the points curves were flattened into, against [`flatten::MAX_DRAWING_POINTS`].
/// Errors name the path. Groups are walked with a work list, so no depth of nesting can
/// overflow the stack.
fn collect(
    g: &usvg::Group,
    height: f64,
    tol: f64,
    select: &Select<'_>,
    flattened: &mut usize,
    out: &mut Vec<Polyline>,
    warnings: &mut Vec<String>,
) -> Result<(), String> {
    let mut todo: Vec<(&usvg::Group, bool)> = vec![(g, select.layers.is_empty())];
    while let Some((g, taken)) = todo.pop() {
        let taken = taken || select.takes(g);
        // children in document order: groups are taken up after their siblings' paths,
        // which changes no geometry
        for node in g.children() {
            match node {
                usvg::Node::Group(g) => todo.push((g, taken)),
                usvg::Node::Path(_) if !taken => {}
                usvg::Node::Path(p) => path(p, height, tol, flattened, out).map_err(|what| {
                    if p.id().is_empty() {
                        format!("a path {what}")
                    } else {
                        format!("path \"{}\" {what}", p.id())
                    }
                })?,
                _ if !taken => {}
                usvg::Node::Image(_) => warnings.push(format!("image {} skipped", node.id())),
                #[allow(unreachable_patterns)]
                _ => warnings.push(format!("text {} skipped", node.id())),
            }
        }
    }
    Ok(())
}

/// The subpaths of `p` as polylines in mm; a curve that cannot be flattened is refused
/// (the error is the rest of a sentence that starts with the path).
fn path(
    p: &usvg::Path,
    height: f64,
    tol: f64,
    flattened: &mut usize,
    out: &mut Vec<Polyline>,
) -> Result<(), String> {
    let ts = p.abs_transform();
    let to_mm = |q: usvg::tiny_skia_path::Point| {
        let mut q = q;
        ts.map_point(&mut q);
        Point::new(q.x as f64 * MM_PER_PX, (height - q.y as f64) * MM_PER_PX)
    };
    let fit = BiarcOptions {
        tolerance: tol / 2.0,
        ..Default::default()
    };
    let mut cur: Vec<Vertex> = Vec::new();
    // where the subpath's run of straight segments (LineTo) began, and whether it has
    // curves: a run of three or more points is fitted with lines and arcs within the
    // tolerance when it ends
    let mut run_from = 0usize;
    let mut has_curves = false;
    let line_fit = BiarcOptions::with_tolerance(tol);
    let fit_run = |cur: &mut Vec<Vertex>, from: usize| {
        if cur.len() >= from + 3 {
            let pts: Vec<Point> = cur[from..].iter().map(|v| v.pos()).collect();
            let f = fit_points(&pts, false, &line_fit);
            cur.truncate(from);
            cur.extend_from_slice(&f.vertices);
        }
    };
    let mut last = Point::default();
    let finish = |cur: &mut Vec<Vertex>,
                  closed: bool,
                  run_from: usize,
                  has_curves: bool,
                  out: &mut Vec<Polyline>| {
        let first = cur.first().map(|v| v.pos());
        let end = cur.last().map(|v| v.pos());
        let closes = matches!((first, end), (Some(a), Some(b)) if closed || a.dist(b) <= tol);
        if !has_curves && closes && cur.len() >= 3 {
            // a polygon: fitted as a loop, so its closing side is fitted too
            let mut pts: Vec<Point> = cur.iter().map(|v| v.pos()).collect();
            if pts.len() > 1 && pts[0].dist(pts[pts.len() - 1]) <= tol {
                pts.pop();
            }
            let f = fit_points(&pts, true, &line_fit);
            *cur = f.vertices;
            cur.push(cur[0]);
        } else {
            fit_run(cur, run_from);
        }
        let mut vs = std::mem::take(cur);
        if vs.len() < 2 {
            return;
        }
        let first = vs[0].pos();
        let end = vs[vs.len() - 1].pos();
        let closed = closed || first.dist(end) <= tol;
        if closed && first.dist(end) <= tol {
            vs.pop();
        } else if let Some(v) = vs.last_mut() {
            v.bulge = 0.0;
        }
        if vs.len() >= 2
            && vs
                .iter()
                .all(|v| v.pos().is_finite() && v.bulge.is_finite())
        {
            out.push(Polyline::new(vs, closed));
        }
    };
    let mut curve = |cur: &mut Vec<Vertex>, pts: Result<Vec<Point>, flatten::FlattenError>| {
        let pts = pts.map_err(|e| match e {
            flatten::FlattenError::TooManyPoints { .. } => format!(
                "would need more than {} points to stay within {tol} mm of one curve; check its size or use a coarser tolerance",
                flatten::MAX_POINTS
            ),
            other => other.to_string(),
        })?;
        *flattened += pts.len();
        if *flattened > flatten::MAX_DRAWING_POINTS {
            return Err(format!(
                "brings the drawing's curves to more than {} points in all within {tol} mm; use a coarser tolerance",
                flatten::MAX_DRAWING_POINTS
            ));
        }
        let f = fit_points(&pts, false, &fit);
        cur.pop();
        cur.extend_from_slice(&f.vertices);
        Ok(())
    };
    // a curve ends the straight run before it
    use usvg::tiny_skia_path::PathSegment;
    for seg in p.data().segments() {
        match seg {
            PathSegment::MoveTo(q) => {
                finish(&mut cur, false, run_from, has_curves, out);
                last = to_mm(q);
                cur.push(Vertex::line(last));
                (run_from, has_curves) = (0, false);
            }
            PathSegment::LineTo(q) => {
                last = to_mm(q);
                cur.push(Vertex::line(last));
            }
            PathSegment::QuadTo(a, b) => {
                let (a, b) = (to_mm(a), to_mm(b));
                fit_run(&mut cur, run_from);
                curve(&mut cur, flatten::quadratic(last, a, b, tol / 2.0))?;
                (run_from, has_curves) = (cur.len() - 1, true);
                last = b;
            }
            PathSegment::CubicTo(a, b, c) => {
                let (a, b, c) = (to_mm(a), to_mm(b), to_mm(c));
                fit_run(&mut cur, run_from);
                curve(&mut cur, flatten::cubic(last, a, b, c, tol / 2.0))?;
                (run_from, has_curves) = (cur.len() - 1, true);
                last = c;
            }
            PathSegment::Close => {
                let start = cur.first().map(|v| v.pos());
                finish(&mut cur, true, run_from, has_curves, out);
                (run_from, has_curves) = (0, false);
                if let Some(s) = start {
                    last = s;
                }
            }
        }
    }
    finish(&mut cur, false, run_from, has_curves, out);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn circle_and_rect_in_mm_with_y_up() {
        let src = br#"<svg xmlns="http://www.w3.org/2000/svg" width="100mm" height="50mm" viewBox="0 0 200 100">
            <rect x="0" y="0" width="20" height="10" fill="black"/>
            <g transform="translate(100,50)"><circle r="20" fill="black"/></g></svg>"#;
        let s = read(src, "t.svg").unwrap();
        assert_eq!(s.paths.len(), 2);
        let rect = s.paths.iter().find(|p| p.len() == 4).unwrap();
        let b = rect.bounds();
        // viewBox units are half millimetres; the rectangle sits at the top left, y up
        assert!(
            (b.min.x - 0.0).abs() < 1e-3 && (b.max.x - 10.0).abs() < 1e-3,
            "{b:?}"
        );
        assert!(
            (b.max.y - 50.0).abs() < 1e-3 && (b.min.y - 45.0).abs() < 1e-3,
            "{b:?}"
        );
        let circle = s.paths.iter().find(|p| p.len() != 4).unwrap();
        // a circle of radius 10 mm about (50, 25) mm, as arcs; usvg hands it over as four
        // cubics, which are themselves off the circle by up to 2.7e-4 × r
        for seg in circle.segments() {
            for t in [0.0, 0.3, 0.7] {
                let d = seg.point_at(t).dist(Point::new(50.0, 25.0));
                assert!((d - 10.0).abs() < 2.7e-3 + 1e-3, "{d}");
            }
        }
        assert!(circle
            .segments()
            .all(|s| matches!(s, crate::geom::Segment::Arc { .. })));
    }

    /// An Inkscape drawing: two layers (one with a nested group) and a loose path.
    const LAYERED: &[u8] = br#"<svg xmlns="http://www.w3.org/2000/svg" xmlns:inkscape="http://www.inkscape.org/namespaces/inkscape" width="100mm" height="100mm" viewBox="0 0 100 100">
        <g inkscape:groupmode="layer" inkscape:label="Holes" id="layer1">
            <circle cx="10" cy="10" r="1.5"/>
            <g id="more-holes"><circle cx="20" cy="10" r="1.5"/></g>
        </g>
        <g inkscape:groupmode="layer" inkscape:label="Outline" id="layer2">
            <rect x="0" y="0" width="50" height="40"/>
        </g>
        <rect id="loose" x="60" y="60" width="5" height="5"/>
        </svg>"#;

    #[test]
    fn layers_are_read_by_inkscape_label_or_group_id_nested_groups_included() {
        assert_eq!(
            layers(LAYERED, "l.svg").unwrap(),
            ["Holes", "layer1", "more-holes", "Outline", "layer2"]
        );
        let only = |names: &[&str]| {
            let names: Vec<String> = names.iter().map(|s| s.to_string()).collect();
            read_layers(LAYERED, "l.svg", 1e-3, &names).map(|d| d.shape.paths.len())
        };
        assert_eq!(only(&[]).unwrap(), 4);
        assert_eq!(only(&["holes"]).unwrap(), 2);
        assert_eq!(only(&["layer1"]).unwrap(), 2);
        assert_eq!(only(&["MORE-HOLES"]).unwrap(), 1);
        assert_eq!(only(&["Outline", "more-holes"]).unwrap(), 2);
        let placed = paths_in_groups(LAYERED, "l.svg").unwrap();
        assert_eq!(placed.len(), 4);
        assert_eq!(
            placed[3],
            ("rect \"loose\"".to_string(), Vec::<String>::new())
        );
        // without ids, elements are named by their kind and place among those of the kind
        assert_eq!(placed[0].0, "circle #1");
        assert_eq!(placed[1].0, "circle #2");
        assert_eq!(placed[2].0, "rect #1");
        let drawn = placed_paths(LAYERED, "l.svg", 1e-3).unwrap();
        let d = crate::ops::drill::circle_of(&drawn[1].paths[0]).map(|(c, r)| (c, 2.0 * r));
        assert!(
            d.is_some_and(|(c, d)| c.dist(Point::new(20.0, 90.0)) < 1e-6 && (d - 3.0).abs() < 1e-3),
            "{d:?}"
        );
        assert!(placed
            .iter()
            .any(|(_, g)| g == &["Holes", "layer1", "more-holes"]));
        let e = only(&["Text"]).unwrap_err().to_string();
        assert!(
            e.contains("Text") && e.contains("Holes, layer1, more-holes, Outline, layer2"),
            "{e}"
        );
    }
}
