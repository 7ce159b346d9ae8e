#!/usr/bin/env python3
"""Drop-cutter heights from OpenCAMLib for several cutters, each over its own points (the
corpus test's gouge check).

usage: ocl_heights.py PART.stl JOB.json OUT.json

JOB.json: {"min_z": z, "jobs": [{"name": "...", "shape": "ball"|"flat"|"bull",
           "diameter": d, "corner_radius": r, "points": [[x, y], ...]}, ...]}
OUT.json: {"version": "...", "triangles": n, "heights": {name: [z, ...]}}

As in ocl_dropcutter.py: BallCutter(d, length), CylCutter(d, length),
BullCutter(d, corner_radius, length); a CL point's z is the tool tip, and a point with
nothing under the cutter keeps min_z.
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


def cutter_of(c, length=1000.0):
    d = float(c["diameter"])
    if c["shape"] == "ball":
        return ocl.BallCutter(d, length)
    if c["shape"] == "flat":
        return ocl.CylCutter(d, length)
    if c["shape"] == "bull":
        return ocl.BullCutter(d, float(c["corner_radius"]), length)
    raise SystemExit("unknown cutter shape %r" % c["shape"])


def main():
    stl, job_path, out_path = sys.argv[1:4]
    with open(job_path) as f:
        job = json.load(f)
    surf = ocl.STLSurf()
    ocl.STLReader(stl, surf)
    if surf.size() == 0:
        sys.stderr.write("OpenCAMLib read no triangles from %s\n" % stl)
        sys.exit(4)
    heights = {}
    for j in job["jobs"]:
        # the batch keeps a bare pointer to the cutter: it must outlive the run
        cutter = cutter_of(j)
        bdc = ocl.BatchDropCutter()
        bdc.setSTL(surf)
        bdc.setCutter(cutter)
        for x, y in j["points"]:
            bdc.appendPoint(ocl.CLPoint(x, y, job["min_z"]))
        bdc.run()
        heights[j["name"]] = [p.z for p in bdc.getCLPoints()]
    with open(out_path, "w") as f:
        json.dump({"version": ocl.version(), "triangles": surf.size(), "heights": heights}, f)


if __name__ == "__main__":
    main()
