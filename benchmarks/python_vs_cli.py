#!/usr/bin/env python3
"""Side by side: the same extraction by the `extract` command and by the Python module.

Writes a smooth float32 volume (a gyroid, N^3 samples) as NRRD, then times, alternately, REPS times each:
  cli    `extract v.nhdr --iso 0 -o cli.cip -q` (wall clock of the process: start, read, build, write)
  path   cip.extract("v.nhdr", 0).save("py.cip")                       (the same file read by the module)
  array  cip.extract(np.fromfile(...).reshape(..., order="F"), 0).save (numpy array in, one conversion)
and prints the medians and the ratios python / cli (issue 36 asks for at most 1.10). The module's path run
writes the same bytes as the command (checked).

    PYTHONPATH=build/python /usr/bin/python3 benchmarks/python_vs_cli.py [--build build] [--n 192] [--reps 3]
"""
import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np


def volume(n):
    t = np.linspace(-1, 1, n, dtype=np.float32)
    x, y, z = t[:, None, None], t[None, :, None], t[None, None, :]
    k = np.float32(10.0)
    return np.sin(k * x) * np.cos(k * y) + np.sin(k * y) * np.cos(k * z) + np.sin(k * z) * np.cos(k * x)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--build", default="build")
    parser.add_argument("--n", type=int, default=192)
    parser.add_argument("--reps", type=int, default=3)
    args = parser.parse_args()
    sys.path.insert(0, os.path.join(args.build, "python"))
    import cip

    extract = os.path.join(args.build, "extract", "extract")
    with tempfile.TemporaryDirectory() as tmp:
        n = args.n
        np.asfortranarray(volume(n)).ravel(order="F").tofile(os.path.join(tmp, "v.raw"))  # x fastest
        nhdr = os.path.join(tmp, "v.nhdr")
        with open(nhdr, "w") as f:
            f.write("NRRD0004\ntype: float\ndimension: 3\nsizes: %d %d %d\nspacings: 1 1 1\nencoding: raw\n"
                    "endian: little\ndata file: v.raw\n" % (n, n, n))
        cli_out, py_out = os.path.join(tmp, "cli.cip"), os.path.join(tmp, "py.cip")

        def cli():
            subprocess.run([extract, nhdr, "--iso", "0", "-o", cli_out, "-q"], check=True)

        def path():
            cip.extract(nhdr, 0.0).save(py_out)

        def array():
            data = np.fromfile(os.path.join(tmp, "v.raw"), np.float32).reshape((n, n, n), order="F")
            cip.extract(data, 0.0).save(py_out)

        runs = {"cli": [], "path": [], "array": []}
        for _ in range(args.reps):
            for name, run in (("cli", cli), ("path", path), ("array", array)):
                start = time.perf_counter()
                run()
                runs[name].append(time.perf_counter() - start)
        path()
        same = open(cli_out, "rb").read() == open(py_out, "rb").read()
        model = cip.load(cli_out)
    median = {k: statistics.median(v) for k, v in runs.items()}
    print("gyroid %d^3 float32, %d cells, %d runs each, median wall seconds:" % (n, model.n_cells, args.reps))
    for name in ("cli", "path", "array"):
        print("  %-5s %.3f s   (runs: %s)" % (name, median[name], ", ".join("%.3f" % t for t in runs[name])))
    print("ratio python/cli: file path %.3f, numpy array %.3f (at most 1.10 asked)" %
          (median["path"] / median["cli"], median["array"] / median["cli"]))
    print("module's model from the file equals the command's byte for byte: %s" % same)
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
