#!/usr/bin/env python3
"""Anchors for the 3D benchmark (benches/mesh3d.rs), timed in the same run.

  anchors.py ocl PART.stl POINTS.json SHAPE DIAMETER CORNER OUT.json
      OpenCAMLib BatchDropCutter over the points (tool tip heights); OUT gets the
      heights, the seconds and the threads used.
  anchors.py meshlib PART.stl DISTANCE VOXELS OUT.stl OUT.json
      MeshLib offsetMesh with a voxel size suggested for about VOXELS voxels; OUT.json
      gets the seconds and the faces.
  anchors.py meshlib_voxel PART.stl DISTANCE VOXEL_SIZE MODE OUT.stl OUT.json
      MeshLib at an explicit voxel size, MODE `offset` (offsetMesh) or `sharp`
      (sharpOffsetMesh, which moves vertices onto sharp edges); OUT.json as above.
"""
import json
import sys
import time


def ocl_run(stl, points_path, shape, d, corner, out):
    import opencamlib as ocl

    with open(points_path) as f:
        job = json.load(f)
    surf = ocl.STLSurf()
    ocl.STLReader(stl, surf)
    d = float(d)
    cutter = {
        "ball": lambda: ocl.BallCutter(d, 1000.0),
        "flat": lambda: ocl.CylCutter(d, 1000.0),
        "bull": lambda: ocl.BullCutter(d, float(corner), 1000.0),
    }[shape]()
    bdc = ocl.BatchDropCutter()
    bdc.setSTL(surf)
    bdc.setCutter(cutter)
    for x, y in job["points"]:
        bdc.appendPoint(ocl.CLPoint(x, y, job["min_z"]))
    t = time.perf_counter()
    bdc.run()
    dt = time.perf_counter() - t
    zs = [p.z for p in bdc.getCLPoints()]
    with open(out, "w") as f:
        json.dump({"seconds": dt, "heights": zs, "threads": bdc.getThreads(),
                   "version": ocl.version()}, f)


def meshlib_run(stl, distance, voxels, out_stl, out_json):
    import meshlib.mrmeshpy as mm

    m = mm.loadMesh(stl)
    p = mm.OffsetParameters()
    p.voxelSize = mm.suggestVoxelSize(mm.MeshPart(m), float(voxels))
    t = time.perf_counter()
    r = mm.offsetMesh(mm.MeshPart(m), float(distance), p)
    dt = time.perf_counter() - t
    mm.saveMesh(r, out_stl)
    with open(out_json, "w") as f:
        json.dump({"seconds": dt, "faces": r.topology.numValidFaces(),
                   "voxel": p.voxelSize}, f)


def meshlib_voxel_run(stl, distance, voxel, mode, out_stl, out_json):
    import meshlib.mrmeshpy as mm

    m = mm.loadMesh(stl)
    if mode == "sharp":
        p = mm.SharpOffsetParameters()
        p.voxelSize = float(voxel)
        t = time.perf_counter()
        r = mm.sharpOffsetMesh(mm.MeshPart(m), float(distance), p)
    else:
        p = mm.OffsetParameters()
        p.voxelSize = float(voxel)
        t = time.perf_counter()
        r = mm.offsetMesh(mm.MeshPart(m), float(distance), p)
    dt = time.perf_counter() - t
    mm.saveMesh(r, out_stl)
    with open(out_json, "w") as f:
        json.dump({"seconds": dt, "faces": r.topology.numValidFaces(),
                   "voxel": p.voxelSize}, f)


if __name__ == "__main__":
    if sys.argv[1] == "ocl":
        ocl_run(*sys.argv[2:8])
    elif sys.argv[1] == "meshlib":
        meshlib_run(*sys.argv[2:7])
    elif sys.argv[1] == "meshlib_voxel":
        meshlib_voxel_run(*sys.argv[2:8])
    else:
        raise SystemExit(__doc__)
