#!/usr/bin/env python3
"""Extraction time of masks and label maps against the same volume's plain extraction (docs/method.md,
"Masks and label maps"): whole extract processes, run in turn (mask, plain, mask, plain, ...), median of the
paired ratios of wall and CPU time.

Volumes (written to a temporary folder): a 200^3 uint8 mask of a torus and a ball; the CT tooth of
../shared/data thresholded at 128; a 200^3 label map of three classes (background, the torus as label 1, the
ball as label 2, touching), of which label 1 is extracted. The plain run is `--reconstruction monotone` on the
same file at isovalue 0.5.

Usage: /usr/bin/python3 benchmarks/mask_timing.py [--build build] [--runs 5]
"""
import argparse
import os
import resource
import statistics
import subprocess
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def write_nrrd(path, array):
    """A uint8 volume indexed [x, y, z] as a raw NRRD."""
    with open(path, "wb") as f:
        f.write(("NRRD0004\ntype: uint8\ndimension: 3\nsizes: %d %d %d\nencoding: raw\n\n" % array.shape).encode())
        f.write(np.ascontiguousarray(array.transpose(2, 1, 0)).tobytes())


def torus_and_ball(n=200):
    x, y, z = (np.indices((n, n, n)).astype(np.float32) - np.array([100.3, 99.6, 100.1])[:, None, None, None])
    torus = (np.sqrt(x * x + y * y) - 50) ** 2 + z * z < 18 ** 2
    ball = (x - 10) ** 2 + (y - 5) ** 2 + (z - 30) ** 2 < 40 ** 2
    return torus, ball


def timed(cmd):
    """Wall and CPU seconds (user + system) of one run of cmd."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--build", default=os.path.join(ROOT, "build"))
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    extract = os.path.join(args.build, "extract", "extract")
    with tempfile.TemporaryDirectory() as tmp:
        torus, ball = torus_and_ball()
        cases = []
        mask = os.path.join(tmp, "mask200.nrrd")
        write_nrrd(mask, (torus | ball).astype(np.uint8))
        cases.append(("200^3 mask, torus and ball", mask, ["--iso", "0.5"]))
        labels = os.path.join(tmp, "labels200.nrrd")
        write_nrrd(labels, np.where(ball, 2, np.where(torus, 1, 0)).astype(np.uint8))
        cases.append(("200^3 label map, label 1 of 3 classes", labels, ["--label", "1"]))
        raw = os.path.join(ROOT, "..", "shared", "data", "tooth_103x94x161_uint8.raw")
        if os.path.exists(raw):
            tooth = os.path.join(tmp, "tooth-mask.nrrd")
            ct = np.fromfile(raw, np.uint8).reshape(161, 94, 103).transpose(2, 1, 0)
            write_nrrd(tooth, (ct > 128).astype(np.uint8))
            cases.append(("CT tooth > 128", tooth, ["--iso", "0.5"]))
        out = os.path.join(tmp, "out.cip")
        print("| volume | mask / plain, wall (median of %d pairs) | CPU |" % args.runs)
        print("|---|---|---|")
        for name, path, options in cases:
            a = [extract, path, *options, "-q", "-o", out]
            b = [extract, path, "--iso", "0.5", "--reconstruction", "monotone", "-q", "-o", out]
            timed(a), timed(b)  # warm the page cache
            wall, cpu = [], []
            for _ in range(args.runs):
                (wa, ca), (wb, cb) = timed(a), timed(b)
                wall.append(wa / wb)
                cpu.append(ca / cb)
            print(f"| {name} | {statistics.median(wall):.2f} | {statistics.median(cpu):.2f} |", flush=True)


if __name__ == "__main__":
    main()
