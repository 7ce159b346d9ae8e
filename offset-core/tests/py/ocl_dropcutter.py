#!/usr/bin/env python3
"""Drop-cutter heights from OpenCAMLib's BatchDropCutter, for the interop test.

usage: ocl_dropcutter.py PART.stl JOB.json OUT.json

JOB.json: {"min_z": z, "points": [[x, y], ...],
           "cutters": [{"name": "...", "shape": "ball"|"flat"|"bull",
                        "diameter": d, "corner_radius": r}, ...]}
OUT.json: {"version": "...", "heights": {name: [z, ...]}}  (tool-tip heights, as machlink's)

OpenCAMLib's cutters take the diameter (BallCutter(d, length), CylCutter(d, length),
BullCutter(d, corner_radius, length)); its CL points' z is the tool tip, and a point
with nothing under the cutter keeps the z it was given (min_z).
"""
import json
import sys

try:
    import opencamlib as ocl
except ImportError as e:  # the Rust test turns this into its failure message
    sys.stderr.write(
        "the Python package opencamlib is not installed (%s): "
        "pip install -r .ci/requirements.txt\n" % e
    )
    sys.exit(3)


def main():
    stl, job_path, out_path = sys.argv[1:4]
    with open(job_path) as f:
        job = json.load(f)
    surf = ocl.STLSurf()
    ocl.STLReader(stl, surf)
    if surf.size() == 0:
        sys.stderr.write("OpenCAMLib read no triangles from %s\n" % stl)
        sys.exit(4)
    length = 1000.0  # longer than any part: only the end's shape matters to drop-cutter
    heights = {}
    for c in job["cutters"]:
        d = float(c["diameter"])
        if c["shape"] == "ball":
            cutter = ocl.BallCutter(d, length)
        elif c["shape"] == "flat":
            cutter = ocl.CylCutter(d, length)
        elif c["shape"] == "bull":
            cutter = ocl.BullCutter(d, float(c["corner_radius"]), length)
        else:
            raise SystemExit("unknown cutter shape %r" % c["shape"])
        bdc = ocl.BatchDropCutter()
        bdc.setSTL(surf)
        bdc.setCutter(cutter)
        for x, y in job["points"]:
            bdc.appendPoint(ocl.CLPoint(x, y, job["min_z"]))
        bdc.run()
        heights[c["name"]] = [p.z for p in bdc.getCLPoints()]
    with open(out_path, "w") as f:
        json.dump({"version": ocl.version(), "triangles": surf.size(), "heights": heights}, f)


if __name__ == "__main__":
    main()
