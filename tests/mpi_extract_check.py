#!/usr/bin/env python3
"""extract under mpirun (docs/mpi.md): the model file of `mpirun -np N extract ARGS` must equal, byte for byte,
the one of the plain `extract ARGS`, for N = 1, 2, 3, on the bundled sample, a terraced volume, an analytic field, and the shared
tooth CT and OpenVDB sphere when ../shared/data has them, with both methods. A failing rank must fail the run
with its message and leave no model file.

Usage: mpi_extract_check.py --extract build/extract/extract --mpirun /usr/bin/mpirun --root .
"""
import argparse
import filecmp
import os
import subprocess
import sys
import tempfile


def terraces(tmp):
    """A 30^3 uint8 ball that climbs 1.3 levels per voxel: extract raises the isovalue 128 over its terraces
    (docs/method.md, "Integer samples at an integer isovalue"), decided from each rank's slabs."""
    import math
    path = os.path.join(tmp, "terraces.nrrd")
    body = bytearray()
    for n in range(27000):
        i, j, k = n % 30 - 14.6, n // 30 % 30 - 15.3, n // 900 - 14.8
        body.append(int(math.floor(128 + 1.3 * (10.2 - math.sqrt(i * i + j * j + k * k)) + 0.5)))
    with open(path, "wb") as f:
        f.write(b"NRRD0004\ntype: uint8\ndimension: 3\nsizes: 30 30 30\nencoding: raw\n\n" + bytes(body))
    return path


def cases(root, tmp):
    """(name, extract arguments before -o) for every input present."""
    shared = os.path.join(root, "..", "shared", "data")
    out = [
        ("blobs", [os.path.join(root, "data", "blobs.nrrd"), "--iso", "128"]),
        ("terraces", [terraces(tmp), "--iso", "128"]),
        ("sphere48", ["sphere", "--resolution", "48"]),
        # Marschner-Lobb with exact normals leaves cells for the rounds after the first (split) one.
        ("marschner-lobb32", ["marschner-lobb", "--resolution", "32", "--normals", "exact"]),
    ]
    tooth = os.path.join(shared, "tooth.nhdr")
    if os.path.exists(tooth):
        out.append(("tooth", [tooth, "--iso", "120"]))
    vdb = os.path.join(shared, "vdb", "sphere.vdb")
    if os.path.exists(vdb):
        out.append(("vdb-sphere", [vdb]))
    return out


def run(cmd, env=None):
    return subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)


def mpirun_prefix(mpirun, n):
    # CI runs as root; the machine has fewer cores than some runs have ranks.
    return [mpirun, "--allow-run-as-root", "--oversubscribe", "-np", str(n)]


def check_identical(args, tmp):
    failures = []
    skip = set(filter(None, args.skip.split(",")))
    for name, inp in cases(args.root, tmp):
        if name in skip:
            continue
        for method in ("fitted", "paper"):
            if f"{name}:{method}" in skip:
                continue
            plain = os.path.join(tmp, f"{name}-{method}.cip")
            base = [args.extract] + inp + ["--method", method, "--quiet", "--threads", "1"]
            r = run(base + ["-o", plain])
            if r.returncode != 0:
                failures.append(f"{name} {method}: plain run failed: {r.stderr.strip()}")
                continue
            for n in args.ranks:
                out = os.path.join(tmp, f"{name}-{method}-np{n}.cip")
                stats = out + ".json"
                r = run(mpirun_prefix(args.mpirun, n) + base + ["-o", out, "--stats-json", stats])
                if r.returncode != 0:
                    failures.append(f"{name} {method} np {n}: failed: {r.stderr.strip()}")
                    continue
                same = filecmp.cmp(plain, out, shallow=False)
                print(f"{name:18s} {method:6s} np {n}: {'identical' if same else 'DIFFERENT'} "
                      f"({os.path.getsize(out)} bytes)")
                if not same:
                    failures.append(f"{name} {method} np {n}: model differs from the plain run's")
                failures += check_stats(stats, n, f"{name} {method} np {n}")
                if name == "terraces" and method == "fitted":
                    import json
                    with open(stats) as f:
                        raise_ = json.load(f)["fitting"]["isovalue_raise"]
                    if raise_ != 1 / 64:
                        failures.append(f"{name} {method} np {n}: isovalue raised by {raise_}, not 1/64")
                if name in ("blobs", "terraces", "tooth"):  # dense files: each rank reads its own slabs
                    failures += check_own_slabs(stats, n, f"{name} {method} np {n}")
    return failures


def check_stats(path, n, what):
    import json
    with open(path) as f:
        s = json.load(f)
    mpi = s.get("mpi", {})
    cells = s["model"]["non_empty_cells"]
    per = mpi.get("cells_per_rank", [])
    if mpi.get("ranks") != n or len(per) != n or sum(per) != cells or max(per) - min(per) > 1:
        return [f"{what}: stats mpi {mpi} do not split {cells} cells between {n} ranks"]
    if (mpi.get("exchanged_bytes", -1) > 0) != (n > 1) or mpi.get("exchange_seconds", -1) < 0:
        return [f"{what}: stats mpi {mpi}: rank 0 exchanged bytes with {n - 1} other ranks?"]
    return []


def check_own_slabs(path, n, what):
    """Under mpirun, each rank of a dense file's build read only the slices of its cell layers plus the halo
    (docs/mpi.md): the stats say which slices each read."""
    import json
    with open(path) as f:
        mpi = json.load(f)["mpi"]
    if n == 1:
        return [] if not mpi.get("reads_own_slabs") else [f"{what}: one rank cannot split its reading"]
    layers, ranges = mpi.get("cell_layers_per_rank", []), mpi.get("slice_range_per_rank", [])
    read = mpi.get("slices_read_per_rank", [])
    if not mpi.get("reads_own_slabs") or len(layers) != n or len(ranges) != n or len(read) != n:
        return [f"{what}: stats mpi {mpi} do not say that each rank read its own slabs"]
    slices = layers[-1][1] + 1  # the volume's slices: one more than its cell layers
    halo = 16  # more than these inputs' references reach (brickApron, Auto's estimate; none is a mask: maskReach is 24)
    failures = []
    for r in range(n):
        (c0, c1), (z0, z1) = layers[r], ranges[r]
        if r > 0 and c0 != layers[r - 1][1]:
            failures.append(f"{what}: rank {r} builds layers {layers[r]} after {layers[r - 1]}")
        if z0 < c0 - halo or z1 > c1 + 1 + halo or z1 - z0 >= slices or read[r] < z1 - z0:
            failures.append(f"{what}: rank {r} (cell layers {c0}..{c1}) read slices {z0}..{z1} "
                            f"({read[r]} in all) of {slices}")
    if layers[0][0] != 0:
        failures.append(f"{what}: the ranks' layers {layers} do not start at 0")
    return failures


def check_failures(args, tmp):
    """A failing rank fails the whole run with its message and no model file."""
    failures = []
    out = os.path.join(tmp, "failed.cip")
    base = [args.extract, "sphere", "--resolution", "32", "--quiet", "-o", out]
    # A rank failing on its own (CIP_TEST_FAIL_RANK, the test-only fault injection of docs/mpi.md): the last.
    for n in (2, 3):
        env = dict(os.environ, CIP_TEST_FAIL_RANK=str(n - 1))
        r = run(mpirun_prefix(args.mpirun, n) + ["-x", "CIP_TEST_FAIL_RANK"] + base, env=env)
        wanted = f"rank {n - 1} of {n}"
        print(f"failing rank {n - 1} of {n}: exit {r.returncode}")
        if r.returncode == 0 or wanted not in r.stderr or "CIP_TEST_FAIL_RANK" not in r.stderr:
            failures.append(f"failing rank {n - 1} of {n}: exit {r.returncode}, stderr: {r.stderr.strip()}")
        if os.path.exists(out):
            failures.append(f"failing rank {n - 1} of {n}: left {out}")
    # A rank killed (SIGKILL, CIP_TEST_FAIL_HOW=kill): mpirun ends the others, the run fails, no file.
    env = dict(os.environ, CIP_TEST_FAIL_RANK="1", CIP_TEST_FAIL_HOW="kill")
    r = run(mpirun_prefix(args.mpirun, 2) + ["-x", "CIP_TEST_FAIL_RANK", "-x", "CIP_TEST_FAIL_HOW"] + base, env=env)
    print(f"killed rank 1 of 2: exit {r.returncode}")
    if r.returncode == 0 or os.path.exists(out):
        failures.append(f"killed rank 1 of 2: exit {r.returncode}, file left: {os.path.exists(out)}")
    # A truncated raw file: every rank's read fails with the reader's message.
    raw = os.path.join(tmp, "short.raw")
    with open(raw, "wb") as f:
        f.write(bytes(range(256)) * 30)  # 7680 of the 20 x 20 x 20 = 8000 bytes
    r = run(mpirun_prefix(args.mpirun, 2) +
            [args.extract, raw, "--dims", "20,20,20", "--type", "uint8", "--iso", "100", "--quiet", "-o", out])
    print(f"truncated raw, np 2: exit {r.returncode}")
    if r.returncode == 0 or "extract: error (rank" not in r.stderr:
        failures.append(f"truncated raw under mpirun: exit {r.returncode}, stderr: {r.stderr.strip()}")
    if os.path.exists(out):
        failures.append(f"truncated raw under mpirun: left {out}")
    # The plain run ignores MPI entirely: the same fault injection fails it as a one-rank run.
    env = dict(os.environ, CIP_TEST_FAIL_RANK="0")
    r = run(base, env=env)
    if r.returncode == 0 or os.path.exists(out):
        failures.append(f"plain run with a failure injected: exit {r.returncode}")
    return failures


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--extract", required=True)
    p.add_argument("--mpirun", required=True)
    p.add_argument("--root", required=True)
    p.add_argument("--ranks", default="1,2,3")
    p.add_argument("--part", choices=["identical", "failures"], default="identical")
    p.add_argument("--skip", default="",
                   help="comma-separated cases (e.g. tooth) or case:method pairs (e.g. vdb-sphere:paper) to leave out")
    args = p.parse_args()
    args.ranks = [int(n) for n in args.ranks.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        failures = check_identical(args, tmp) if args.part == "identical" else check_failures(args, tmp)
    for f in failures:
        print("FAIL:", f, file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
