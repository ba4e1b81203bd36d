#!/usr/bin/python3
"""Peak memory of `extract` on sparse OpenVDB level sets against their active voxels and their index box.

Eight spheres, one near each corner of a cubic box, are written as one level set (Debian's python3-openvdb)
and extracted by `extract` (one thread); the peak resident memory is the child process's own accounting. The
same spheres in boxes from 256 to 4096 voxels show whether memory follows the active voxels (it should) or
the box (it must not). Writes a Markdown table to stdout (benchmarks/results/sparse-memory.md).

    /usr/bin/python3 benchmarks/sparse_memory.py [--build-dir build] [--radii 20,40,80] [--boxes 256,1024,4096]
"""
import argparse
import os
import subprocess
import sys
import tempfile
import time

import pyopenvdb as vdb

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def write_spheres(path, radius, box):
    """Eight spheres of `radius` voxels, each `radius` + 8 voxels in from a corner of [0, box - 1]^3."""
    inset = radius + 8.0
    grid = None
    for corner in range(8):
        centre = tuple(inset + 0.37 * a if not (corner >> a) & 1 else box - 1 - inset - 0.21 * a for a in range(3))
        sphere = vdb.createLevelSetSphere(radius=float(radius), center=centre, voxelSize=1.0, halfWidth=3.0)
        if grid is None:
            grid = sphere
        else:
            grid.combine(sphere, lambda a, b: min(a, b))
    grid.name = "surface"
    vdb.write(path, grids=[grid])
    return grid.activeVoxelCount()


def run_extract(exe, path, out):
    """Peak resident MiB, wall seconds and the model's summary line of one extraction."""
    start = time.monotonic()
    proc = subprocess.Popen([exe, path, "-o", out, "--threads", "1"], stderr=subprocess.PIPE, text=True)
    _, status, usage = os.wait4(proc.pid, 0)
    err = proc.stderr.read()
    if os.waitstatus_to_exitcode(status) != 0:
        sys.exit("extract failed on %s:\n%s" % (path, err))
    summary = next((line for line in err.splitlines() if "non-empty cells" in line), "")
    return usage.ru_maxrss / 1024.0, time.monotonic() - start, summary


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--build-dir", default=os.path.join(ROOT, "build"))
    parser.add_argument("--radii", default="20,40,80")
    parser.add_argument("--boxes", default="256,1024,4096")
    args = parser.parse_args()
    exe = os.path.join(args.build_dir, "extract", "extract")
    radii = [int(r) for r in args.radii.split(",")]
    boxes = [int(b) for b in args.boxes.split(",")]
    print("| sphere radius | box | active voxels | patch cells | peak MiB | peak bytes / active voxel | seconds |")
    print("|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for radius in radii:
            for box in boxes:
                if box < 4 * (radius + 8):
                    continue
                path = os.path.join(tmp, "spheres.vdb")
                voxels = write_spheres(path, radius, box)
                peak, seconds, summary = run_extract(exe, path, os.path.join(tmp, "spheres.cip"))
                cells = summary.split(":")[1].split("non-empty")[0].strip() if ":" in summary else "?"
                print("| %d | %d³ | %d | %s | %.0f | %.0f | %.2f |"
                      % (radius, box, voxels, cells, peak, peak * 2**20 / voxels, seconds), flush=True)


if __name__ == "__main__":
    main()
