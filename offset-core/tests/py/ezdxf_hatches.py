"""Writes DXF drawings of hatches with ezdxf (every boundary-path kind, islands, several
loops, the three hatch styles, a hatch in a block) as ASCII and as binary DXF, and a
manifest of what each drawing's filled area is, worked out here from the geometry.

Usage: python3 ezdxf_hatches.py OUT_DIR

Writes OUT_DIR/NAME.dxf and OUT_DIR/NAME_bin.dxf for every drawing and
OUT_DIR/expected.json: {NAME: {"regions": n, "area": mm², "inside": [[x, y], …],
"outside": [[x, y], …]}}. Run by offset-core/tests/it/import_hatch.rs and
daemon/tests/it/hatch_cli.rs; needs the ezdxf package (.ci/requirements.txt).
"""

import json
import math
import os
import sys

import ezdxf


def polygon_area(pts):
    return abs(
        sum(
            pts[i][0] * pts[(i + 1) % len(pts)][1] - pts[(i + 1) % len(pts)][0] * pts[i][1]
            for i in range(len(pts))
        )
        / 2.0
    )


def bezier(p, n=20000):
    out = []
    for k in range(n + 1):
        t = k / n
        u = 1 - t
        out.append(
            tuple(
                u**3 * p[0][i] + 3 * u * u * t * p[1][i] + 3 * u * t * t * p[2][i] + t**3 * p[3][i]
                for i in range(2)
            )
        )
    return out


def new_doc(version="R2018"):
    doc = ezdxf.new(version)
    doc.header["$INSUNITS"] = 4  # mm
    return doc


def square(x0, y0, x1, y1):
    return [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]


def polyline_bulges(msp):
    """A stadium (bulged polyline path) with a square island (polyline path)."""
    h = msp.add_hatch(color=1)
    h.paths.add_polyline_path([(0, 0, 0), (40, 0, 1), (40, 20, 0), (0, 20, 1)], is_closed=True, flags=1)
    h.paths.add_polyline_path(square(15, 5, 25, 15), is_closed=True, flags=16)
    return {
        "regions": 1,
        "area": 800 + math.pi * 100 - 100,
        "inside": [[-8, 10], [48, 10], [5, 5], [30, 18]],
        "outside": [[20, 10], [-11, 10], [51, 10], [20, 21]],
    }


def edges(msp):
    """Edge paths: a D of lines and a ccw arc with an island of a full elliptic arc; a
    quarter disc bounded by a clockwise arc; an elliptic sector to 45° (an angle, not the
    ellipse's parameter); a loop closed by a spline edge."""
    out = {"regions": 4, "area": 0.0, "inside": [], "outside": []}
    h = msp.add_hatch(color=2)
    e = h.paths.add_edge_path(flags=1)
    e.add_line((0, 0), (30, 0))
    e.add_arc((30, 15), 15, -90, 90, ccw=True)
    e.add_line((30, 30), (0, 30))
    e.add_line((0, 30), (0, 0))
    isl = h.paths.add_edge_path(flags=16)
    isl.add_ellipse((15, 15), major_axis=(6, 0), ratio=0.5, start_angle=0, end_angle=360)
    out["area"] += 900 + math.pi * 225 / 2 - math.pi * 6 * 3
    out["inside"] += [[40, 15], [2, 2], [15, 11]]
    out["outside"] += [[15, 15], [20.5, 15], [46, 15]]

    # a quarter disc at (60, 0): its arc is clockwise (stored as complements of 360°)
    h = msp.add_hatch(color=3)
    e = h.paths.add_edge_path(flags=1)
    e.add_line((60, 0), (70, 0))
    e.add_arc((60, 0), 10, 0, 90, ccw=False)
    e.add_line((60, 10), (60, 0))
    out["area"] += math.pi * 25
    out["inside"] += [[63, 3], [66, 6]]
    out["outside"] += [[58, 3], [63, -3], [68, 8]]

    # an elliptic sector at (90, 0): from the major axis to the ray at 45°
    a, b = 10.0, 5.0
    h = msp.add_hatch(color=4)
    e = h.paths.add_edge_path(flags=1)
    x45 = math.sqrt(1 / (1 / a**2 + 1 / b**2))  # where the ray y = x meets the ellipse
    e.add_line((90, 0), (90 + a, 0))
    e.add_ellipse((90, 0), major_axis=(a, 0), ratio=b / a, start_angle=0, end_angle=45)
    e.add_line((90 + x45, x45), (90, 0))
    t45 = math.atan2(math.sin(math.pi / 4) / (b / a), math.cos(math.pi / 4))
    out["area"] += a * b * t45 / 2
    out["inside"] += [[95, 1], [92 + 0.9 * x45, 0.8 * x45]]
    out["outside"] += [[95, 6], [91, 3]]

    # a loop at (0, 50) closed by a cubic Bézier as a spline edge (clamped knots)
    ctrl = [(40, 60), (30, 75), (10, 75), (0, 60)]
    h = msp.add_hatch(color=5)
    e = h.paths.add_edge_path(flags=1)
    e.add_line((0, 50), (40, 50))
    e.add_line((40, 50), (40, 60))
    e.add_spline(control_points=ctrl, knot_values=[0, 0, 0, 0, 1, 1, 1, 1], degree=3)
    e.add_line((0, 60), (0, 50))
    out["area"] += polygon_area([(0, 50), (40, 50)] + bezier(ctrl))
    out["inside"] += [[20, 65], [2, 52]]
    out["outside"] += [[20, 72], [1, 62]]
    return out


def islands(style):
    """Squares nested four deep in one hatch of `style` (0 normal, 1 outer, 2 ignore)."""

    def draw(msp):
        h = msp.add_hatch(color=6)
        h.dxf.hatch_style = style
        for k, (x0, x1) in enumerate([(0, 60), (10, 50), (20, 40), (27, 33)]):
            h.paths.add_polyline_path(square(x0, x0, x1, x1), is_closed=True, flags=1 if k == 0 else 16)
        ring = [[5, 5], [55, 30]]
        hole = [[15, 15], [45, 30]]
        inner = [[23, 23], [37, 30]]
        core = [[30, 30]]
        return [
            {"regions": 2, "area": 3600 - 1600 + 400 - 36, "inside": ring + inner, "outside": hole + core},
            {"regions": 1, "area": 3600 - 1600, "inside": ring, "outside": hole + inner + core},
            {"regions": 1, "area": 3600, "inside": ring + hole + inner + core, "outside": [[61, 30]]},
        ][style]

    return draw


def several(msp):
    """One hatch of three separate loops, one of them a circle that is also drawn as a
    CIRCLE entity (as an associative hatch keeps its boundary)."""
    h = msp.add_hatch(color=1)
    h.paths.add_polyline_path(square(0, 0, 20, 10), is_closed=True, flags=1)
    h.paths.add_polyline_path(square(30, 0, 50, 10), is_closed=True, flags=1)
    e = h.paths.add_edge_path(flags=1)
    e.add_arc((70, 5), 5, 0, 360)
    msp.add_circle((70, 5), 5)
    return {
        "regions": 3,
        "area": 400 + math.pi * 25,
        "inside": [[10, 5], [40, 5], [70, 5]],
        "outside": [[25, 5], [60, 5]],
    }


def in_block(doc):
    """A hatch in a block, inserted scaled by 2 and inserted rotated by 90°."""
    blk = doc.blocks.new("PAD")
    h = blk.add_hatch(color=2)
    h.paths.add_polyline_path(square(0, 0, 10, 5), is_closed=True, flags=1)
    msp = doc.modelspace()
    msp.add_blockref("PAD", (100, 0), dxfattribs={"xscale": 2, "yscale": 2})
    msp.add_blockref("PAD", (100, 50), dxfattribs={"rotation": 90})
    return {
        "regions": 2,
        "area": 200 + 50,
        "inside": [[110, 5], [97, 55]],
        "outside": [[121, 5], [103, 55]],
    }


def r12_polylines(doc):
    """R12 (one-byte group codes in binary): a closed POLYLINE with a bulge and a CIRCLE
    island; no HATCH exists in R12."""
    msp = doc.modelspace()
    msp.add_polyline2d([(0, 0), (30, 0), (30, 20), (0, 20)], close=True)
    msp.add_circle((15, 10), 4)
    return {
        "regions": 1,
        "area": 600 - math.pi * 16,
        "inside": [[2, 2]],
        "outside": [[15, 10]],
    }


def main():
    out = sys.argv[1]
    os.makedirs(out, exist_ok=True)
    expected = {}
    drawings = [
        ("polyline_bulges", "R2018", lambda d: polyline_bulges(d.modelspace())),
        ("edges", "R2018", lambda d: edges(d.modelspace())),
        ("islands_normal", "R2018", lambda d: islands(0)(d.modelspace())),
        ("islands_outer", "R2018", lambda d: islands(1)(d.modelspace())),
        ("islands_ignore", "R2018", lambda d: islands(2)(d.modelspace())),
        ("several", "R2000", lambda d: several(d.modelspace())),
        ("in_block", "R2010", in_block),
        ("r12_polylines", "R12", r12_polylines),
    ]
    for name, version, draw in drawings:
        doc = new_doc(version)
        expected[name] = draw(doc)
        doc.saveas(os.path.join(out, name + ".dxf"))
        doc.saveas(os.path.join(out, name + "_bin.dxf"), fmt="bin")
    with open(os.path.join(out, "expected.json"), "w") as f:
        json.dump(expected, f, indent=1)


if __name__ == "__main__":
    main()
