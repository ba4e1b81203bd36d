#!/usr/bin/python3
"""Strong scaling of `extract` under mpirun (docs/mpi.md): whole-process wall time of one extraction as
`mpirun -np 1` and `mpirun -np 2` with one thread per rank, and as one plain process with two threads (the peer:
the same two cores used by threads instead of ranks), each run checked to write the plain run's model bytes.

The runs go in rounds of one of each, in turn, so that every ratio compares runs that saw the same machine load;
the table gives the medians over the rounds and the median of the per-round ratios np 1 / np 2 and
np 1 / threads 2. Writes Markdown to stdout (benchmarks/results/mpi-scaling.md).

Dense files (the tooth CT, and a generated 256^3 uint8 volume of smooth blobs, streaming_memory.py's) are read
per rank under mpirun: each rank reads only its z-slabs plus halo, and the table says how many bytes of the file
each of the two ranks read (the most of the two) against the file's samples.

    /usr/bin/python3 benchmarks/mpi_scaling.py [--build-dir build] [--rounds 7] > benchmarks/results/mpi-scaling.md
"""
import argparse
import filecmp
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHARED = os.path.join(ROOT, "..", "shared", "data")

CASES = [
    ("gyroid, N = 192, fitted", ["gyroid", "--resolution", "192"]),
    ("gyroid, N = 128, fitted", ["gyroid", "--resolution", "128"]),
    ("gyroid, N = 128, paper", ["gyroid", "--resolution", "128", "--method", "paper"]),
    ("tooth CT, iso 120, fitted", [os.path.join(SHARED, "tooth.nhdr"), "--iso", "120"]),
    ("OpenVDB sphere, fitted", [os.path.join(SHARED, "vdb", "sphere.vdb")]),
]


def dense_volume(folder):
    """The generated dense case: 256^3 uint8 blobs as NRRD with raw data (streaming_memory.write_volume)."""
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from streaming_memory import write_volume
    return write_volume(folder, 256)


def timed(cmd, env=None):
    start = time.monotonic()
    r = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
    seconds = time.monotonic() - start
    if r.returncode != 0:
        sys.exit("failed: %s\n%s" % (" ".join(cmd), r.stderr))
    return seconds


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--build-dir", default=os.path.join(ROOT, "build"))
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--mpirun", default="mpirun")
    args = parser.parse_args()
    exe = os.path.join(args.build_dir, "extract", "extract")
    mpirun = [args.mpirun, "--allow-run-as-root", "--oversubscribe", "--bind-to", "none"]
    # No huge-page restart: the inputs are small and the restart would time one more exec in some runs only.
    env = dict(os.environ, CIP_HUGE_PAGES="0")
    rows = []
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        cases = CASES + [("blobs 256³ uint8 NRRD, iso 128, fitted", [dense_volume(tmp), "--iso", "128"])]
        for name, inp in cases:
            if not os.path.exists(inp[0]) and "/" in inp[0]:
                continue
            out = {k: os.path.join(tmp, k + ".cip") for k in ("plain", "np1", "np2", "t2")}
            base = [exe] + inp + ["--quiet"]
            cmds = {
                "np1": mpirun + ["-np", "1"] + base + ["--threads", "1", "-o", out["np1"]],
                "np2": mpirun + ["-np", "2"] + base + ["--threads", "1", "-o", out["np2"], "--stats-json",
                                                       os.path.join(tmp, "np2.json")],
                "t2": base + ["--threads", "2", "-o", out["t2"]],
            }
            stats = os.path.join(tmp, "stats.json")
            timed(base + ["--threads", "1", "-o", out["plain"], "--stats-json", stats], env)
            with open(stats) as f:
                s = json.load(f)
            cells = s["model"]["non_empty_cells"]
            build = s["seconds"]
            # The passes split between ranks for a dense volume: all but the reference's Auto choice, and the
            # fit's rounds after the first (both in their timings; so this share is an upper bound).
            split = sum(build[k] for k in ("build_scan", "build_reference", "build_isovertices", "build_assemble",
                                           "build_fit"))
            times = {k: [] for k in cmds}
            exchange = []  # np 2: rank 0's seconds in the exchanges
            for _ in range(args.rounds):
                for k, cmd in cmds.items():
                    times[k].append(timed(cmd, env))
                    if k == "np2":
                        with open(os.path.join(tmp, "np2.json")) as f:
                            mpi = json.load(f)["mpi"]
                        exchange.append(mpi["exchange_seconds"])
                        sent = mpi["exchanged_bytes"]
                        spans = [z1 - z0 for z0, z1 in mpi.get("slice_range_per_rank", [])]
                        read = "%d of %d" % (max(spans), s["input"]["dims"][2]) if spans else None
                    if not filecmp.cmp(out["plain"], out[k], shallow=False):
                        sys.exit("%s: %s wrote another model than the plain run" % (name, k))
            ratio = lambda a, b: statistics.median(x / y for x, y in zip(times[a], times[b]))
            whole = build["build"] + build["read"] + build["write_model"] + build["read_back_model"]
            rows.append((name, cells, split / whole, statistics.median(times["np1"]),
                         statistics.median(times["np2"]), statistics.median(times["t2"]), ratio("np1", "np2"),
                         ratio("np1", "t2"), sent / 1e6, statistics.median(exchange), read))
    load_after = os.getloadavg()
    print("Machine: %s, %d cores (%s); %d rounds, medians; every run's model equal to the plain run's, byte for byte."
          % (platform.node(), os.cpu_count(), platform.processor() or platform.machine(), args.rounds))
    print("Load average (1 min) before and after: %.2f, %.2f (other work on the machine competes with the runs)."
          % (load_before[0], load_after[0]))
    print()
    print("| input | patch cells | split passes, share of the timed stages (upper bound) | np 1 × 1 thread, s | np 2 × 1 thread, s "
          "| 1 process × 2 threads, s | speed-up np 2 | speed-up 2 threads | np 2: MB each rank sends "
          "| np 2: s in exchanges | np 2: z-slices each rank reads, of the volume's |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name, cells, share, np1, np2, t2, r2, rt, mb, ex, rd in rows:
        print("| %s | %d | %.0f %% | %.3f | %.3f | %.3f | %.2f× | %.2f× | %.1f | %.2f | %s |"
              % (name, cells, 100 * share, np1, np2, t2, r2, rt, mb, ex,
                 rd or "all (not a dense file)"))


if __name__ == "__main__":
    main()
