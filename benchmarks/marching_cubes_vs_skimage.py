#!/usr/bin/env python3
"""Side by side: cip.marching_cubes against skimage.measure.marching_cubes on the same arrays.

For each input (a gyroid of N^3 samples as float32, the same as float64 in Fortran order, and a uint8 sphere), times,
alternately, REPS times each, cip.marching_cubes(volume, level) on all threads and on one, and
skimage.measure.marching_cubes(volume, level) (default method 'lewiner'; --method lorensen for the other), prints
the medians and the ratios skimage / cip, and checks that all give the same arrays (vertices, faces, normals,
values) bit for bit.

    PYTHONPATH=build/python /usr/bin/python3 benchmarks/marching_cubes_vs_skimage.py [--build build] [--n 192] [--reps 5]
"""
import argparse
import os
import statistics
import sys
import time

import numpy as np


def gyroid(n):
    t = np.linspace(-1, 1, n, dtype=np.float32)
    x, y, z = t[:, None, None], t[None, :, None], t[None, None, :]
    k = np.float32(10.0)
    return np.sin(k * x) * np.cos(k * y) + np.sin(k * y) * np.cos(k * z) + np.sin(k * z) * np.cos(k * x)


def sphere_uint8(n):
    t = np.linspace(-1, 1, n)
    x, y, z = t[:, None, None], t[None, :, None], t[None, None, :]
    return np.clip(255 * (1 - np.sqrt(x * x + y * y + z * z)), 0, 255).astype(np.uint8)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--build", default="build")
    parser.add_argument("--n", type=int, default=192)
    parser.add_argument("--reps", type=int, default=5)
    parser.add_argument("--method", default="lewiner", choices=["lewiner", "lorensen"])
    args = parser.parse_args()
    sys.path.insert(0, os.path.join(args.build, "python"))
    import cip
    from skimage.measure import marching_cubes

    n = args.n
    inputs = [("gyroid float32", gyroid(n), 0.0),
              ("gyroid float64, Fortran order", np.asfortranarray(gyroid(n), dtype=np.float64), 0.0),
              ("sphere uint8", sphere_uint8(n), 100.5)]
    print("%d^3 samples, method %s, %d runs each (alternating), median wall seconds:" % (n, args.method, args.reps))
    same_everywhere = True
    for name, volume, level in inputs:
        contenders = (("cip", lambda: cip.marching_cubes(volume, level, method=args.method)),
                      ("cip-1", lambda: cip.marching_cubes(volume, level, method=args.method, threads=1)),
                      ("skimage", lambda: marching_cubes(volume, level, method=args.method)))
        runs = {who: [] for who, _ in contenders}
        results = {}
        for _ in range(args.reps):
            for who, run in contenders:
                start = time.perf_counter()
                results[who] = run()
                runs[who].append(time.perf_counter() - start)
        same = all(a.dtype == b.dtype and np.array_equal(a, b)
                   for who in ("cip", "cip-1") for a, b in zip(results[who], results["skimage"]))
        same_everywhere &= same
        m = {k: statistics.median(v) for k, v in runs.items()}
        print("  %-30s %8d faces   cip %.3f s (1 thread %.3f s)   skimage %.3f s   skimage/cip %.2f (1 thread %.2f)"
              "   identical arrays: %s" % (name, len(results["cip"][1]), m["cip"], m["cip-1"], m["skimage"],
                                           m["skimage"] / m["cip"], m["skimage"] / m["cip-1"], same))
    return 0 if same_everywhere else 1


if __name__ == "__main__":
    sys.exit(main())
