#!/usr/bin/python3
"""Bytes of `extract --method paper` (or `fitted`) models against Draco on the marching-cubes mesh of the same
cells, per stream, for one or two builds side by side (docs/model-format.md, "Measured bytes").

    python3 benchmarks/paper_model_bytes.py --build build [--before OTHER_BUILD] [--method fitted]
                                            [--shared-data ../shared/data]

For each case: extract writes the model, its marching-cubes mesh (binary PLY with normals) and, with
--check-storage, how far the stored surface lies from the model as built (the storage bound: 0.01 voxel);
draco_encoder -qp 14 -qn 10 -cl 7 encodes the mesh; cip_bench model-streams (of --build, which reads the files
of both builds) splits the model's bytes. Prints a Markdown table (bytes per patch cell) with one row per case
and build. With --method fitted the cases include the Colin 27 T1 template (Debian's mricron-data) when it is
installed.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DRACO = ["-qp", "14", "-qn", "10", "-cl", "7"]
CASES = [("CT head at 500", ["headsq.nhdr", "--iso", "500"]), ("CT head at 1150", ["headsq.nhdr", "--iso", "1150"]),
         ("tooth at 120", ["tooth.nhdr", "--iso", "120"]), ("smoke at 0.1", ["vdb/smoke.vdb", "--iso", "0.1"]),
         ("gyroid, N = 128", ["gyroid", "--resolution", "128"])]
MRI = "/usr/share/mricron/templates/ch2.nii.gz"  # Colin 27 T1 (181x217x181 uint8)
FITTED_CASES = [("Marschner-Lobb, N = 64", ["marschner-lobb", "--resolution", "64"]),
                ("MRI (Colin 27) at 60", [MRI, "--iso", "60"])]
COLUMNS = [("sign rows", ["sign rows", "cell exceptions", "face pairings"]),
           ("positions", ["positions (low bytes)", "positions (high bytes)"]),
           ("normals", ["normals", "zero normal components"]),
           ("full-precision vertices", ["full-precision vertices"]), ("refined vertices", ["refined vertices"]),
           ("refined coefficients", ["refined coefficients"]),
           ("side coefficients", ["side coefficients"]), ("central coefficients", ["central coefficients"]),
           ("header and framing", ["header", "framing"])]


def run(cmd, **kw):
    print("+ " + " ".join(cmd), file=sys.stderr, flush=True)
    return subprocess.run(cmd, check=True, **kw)


def measure(build, reader, method, label, args, out, draco_bytes):
    model, mesh, stats = (os.path.join(out, label + ext) for ext in (".cip", "-mc.ply", ".json"))
    run([os.path.join(build, "extract", "extract")] + args + ["--method", method, "-o", model, "--mc-mesh", mesh,
                                                              "--check-storage", "--stats-json", stats, "--quiet"])
    if draco_bytes is None:
        drc = os.path.join(out, label + ".drc")
        run(["draco_encoder", "-i", mesh, "-o", drc] + DRACO, stdout=subprocess.DEVNULL)
        draco_bytes = os.path.getsize(drc)
    streams = json.loads(run([os.path.join(reader, "benchmarks", "cip_bench"), "model-streams", "--model", model],
                             capture_output=True, text=True).stdout)
    st = json.load(open(stats))
    cells = streams["cells"]
    row = {"cells": cells, "bytes": streams["file_bytes"], "draco": draco_bytes,
           "distance": st["storage"]["max_distance_voxels"], "write": st["seconds"]["write_model"]}
    for col, names in COLUMNS:
        row[col] = sum(streams["streams"].get(n, 0) for n in names) / cells
    return row, draco_bytes


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--build", required=True)
    ap.add_argument("--before", help="another build to measure side by side (its rows say 'before')")
    ap.add_argument("--method", choices=["paper", "fitted"], default="paper")
    ap.add_argument("--shared-data", default=os.path.join(ROOT, "..", "shared", "data"))
    a = ap.parse_args()
    cases = CASES + [c for c in FITTED_CASES if a.method == "fitted" and (c[1][0] != MRI or os.path.exists(MRI))]
    builds = ([("before", a.before)] if a.before else []) + [("after" if a.before else "", a.build)]
    rows = []
    with tempfile.TemporaryDirectory() as out:
        for index, (name, args) in enumerate(cases):
            if "." in args[0] and not os.path.isabs(args[0]):  # a file of the shared data, not an analytic field
                args = [os.path.join(a.shared_data, args[0])] + args[1:]
            draco = None
            for tag, build in builds:
                row, draco = measure(build, a.build, a.method, "%s-%d" % (tag or "m", index), args, out, draco)
                rows.append((name + (", " + tag if tag else ""), row))
    head = ["model", "patch cells", "bytes", "B/cell", "Draco B/cell", "model / Draco"] + [c for c, _ in COLUMNS] + [
        "max distance (voxels)", "write (s)"]
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for name, r in rows:
        cells = r["cells"]
        cols = [name, "{:,}".format(cells), "{:,}".format(r["bytes"]), "%.2f" % (r["bytes"] / cells),
                "%.2f" % (r["draco"] / cells), "%.2f" % (r["bytes"] / r["draco"])]
        cols += ["%.2f" % r[c] for c, _ in COLUMNS] + ["%.4f" % r["distance"], "%.3f" % r["write"]]
        print("| " + " | ".join(cols) + " |")


if __name__ == "__main__":
    main()
