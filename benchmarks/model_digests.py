#!/usr/bin/env python3
"""SHA-256 digests of the models (and meshes) `extract` builds from a fixed set of inputs.

A change that must not change what is built (a refactoring, a speed-up that keeps the arithmetic) shows it by
giving the same digests before and after:

    python3 benchmarks/model_digests.py --build-dir build-old > before.txt
    python3 benchmarks/model_digests.py --build-dir build > after.txt
    diff before.txt after.txt                 # empty: byte-identical

or, in one step, `--compare before.txt`, which exits 1 and names the cases that differ. The inputs are the bundled
sample, the real volumes of ../shared/data at their suggested isovalues (skipped when the folder is missing) and
the analytic fields with each normal mode, construction and reconstruction; every case is built at 1 and 2
threads, and the two must agree. `--quick` keeps the smaller half of the cases.
"""
import argparse
import hashlib
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def cases(shared, quick):
    """(name, extract arguments) of every case."""
    out = [("blobs", ["data/blobs.nrrd", "--iso", "128"]),
           ("blobs-paper", ["data/blobs.nrrd", "--iso", "128", "--method", "paper"])]
    for field in ["sphere", "torus", "gyroid", "marschner-lobb"]:
        for n in ([16] if quick else [16, 32]):
            for extra in (["--normals", "gradient", "--reconstruction", "monotone"],
                          ["--normals", "gradient", "--reconstruction", "central8"],
                          ["--normals", "exact"], ["--normals", "edge"],
                          ["--normals", "gradient", "--method", "paper", "--central", "interior"]):
                tag = "-".join(a for a in extra if not a.startswith("--"))
                out.append(("%s-%d-%s" % (field, n, tag), [field, "--resolution", str(n)] + extra))
    if shared and os.path.isdir(shared):
        real = [("nucleon", "nucleon.nhdr", "128", []), ("tooth-120", "tooth.nhdr", "120", []),
                ("headsq-1150", "headsq.nhdr", "1150", []), ("headsq-500", "headsq.nhdr", "500", []),
                ("sphere-vdb", "vdb/sphere.vdb", "0", []), ("smoke-0.1", "vdb/smoke.vdb", "0.1", []),
                ("smoke-0.5", "vdb/smoke.vdb", "0.5", [])]
        if quick:
            real = real[:3]
        for name, path, iso, extra in real:
            out.append((name, [os.path.join(shared, path), "--iso", iso] + extra))
            out.append((name + "-paper", [os.path.join(shared, path), "--iso", iso, "--method", "paper"] + extra))
    return out


def digest(path):
    h = hashlib.sha256()
    with open(path, "rb") as f:
        h.update(f.read())
    return h.hexdigest()


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build-dir", default=os.path.join(ROOT, "build"))
    ap.add_argument("--shared-data", default=os.path.join(ROOT, "..", "shared", "data"))
    ap.add_argument("--quick", action="store_true", help="the smaller half of the cases")
    ap.add_argument("--compare", metavar="FILE", help="digests of an earlier run: exit 1 when any case differs")
    args = ap.parse_args()
    extract = os.path.join(args.build_dir, "extract", "extract")
    lines, failed = [], False
    with tempfile.TemporaryDirectory() as tmp:
        for name, argv in cases(args.shared_data, args.quick):
            found = []
            for threads in ("1", "2"):
                model, mc, patch = (os.path.join(tmp, name + suffix) for suffix in (".cip", "-mc.ply", "-patch.ply"))
                subprocess.run([extract] + argv + ["-o", model, "--mc-mesh", mc, "--patch-mesh", patch,
                                                   "--threads", threads, "--quiet"], cwd=ROOT, check=True)
                found.append(" ".join(digest(p)[:16] for p in (model, mc, patch)))
            if found[0] != found[1]:
                print("%s: 1 and 2 threads differ" % name, file=sys.stderr)
                failed = True
            lines.append("%s %s" % (name, found[0]))
            print(lines[-1], flush=True)
    if args.compare:
        before = dict(l.split(" ", 1) for l in open(args.compare).read().splitlines() if l.strip())
        now = dict(l.split(" ", 1) for l in lines)
        differ = [k for k in now if k in before and before[k] != now[k]]
        missing = [k for k in now if k not in before]
        for k in differ:
            print("differs: %s" % k, file=sys.stderr)
        print("%d cases compared, %d differ, %d not in %s" % (len(now) - len(missing), len(differ), len(missing),
                                                            args.compare), file=sys.stderr)
        failed = failed or bool(differ)
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
