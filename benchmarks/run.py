#!/usr/bin/python3
"""Side-by-side benchmarks of cip against marching cubes, OpenVDB, vdb_render and VTK.

One command produces benchmarks/results/report.md, one CSV per section and PNG plots, from runs made in this same
invocation (nothing is copied from earlier runs or typed in by hand):

    python3 benchmarks/run.py            # full run (about 10-15 minutes on 2 cores)
    python3 benchmarks/run.py --quick    # a few seconds per section (what CI runs, so the runner cannot rot)

Sections: extraction speed (cip patches vs cip marching cubes vs OpenVDB volumeToMesh vs VTK flying edges, 1 thread
and all threads), size (model vs marching-cubes PLY vs input), rendering (raycast on the model vs Embree on the
marching-cubes mesh vs vdb_render, same camera and image size) and fidelity against analytic fields.
"""
import argparse
import csv
import json
import os
import platform
import shutil
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


COMMANDS = []  # the measuring commands, listed in the report so a reader can rerun them


def sh(cmd, log=True, **kw):
    print("+ " + " ".join(cmd), file=sys.stderr, flush=True)
    if log:
        COMMANDS.append(" ".join(os.path.relpath(c, ROOT) if os.path.exists(c) else c for c in cmd))
    return subprocess.run(cmd, check=True, **kw)


def timed(cmd):
    t0 = time.perf_counter()
    sh(cmd, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def read_csv(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def write_csv(path, rows, fields):
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields)
        w.writeheader()
        for r in rows:
            w.writerow(r)


def machine():
    cpu = platform.processor() or "unknown"
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem = ""
    try:
        for line in open("/proc/meminfo"):
            if line.startswith("MemTotal"):
                mem = "%.1f GiB" % (int(line.split()[1]) / 2**20)
    except OSError:
        pass
    return "%s, %d cores, %s memory, %s" % (cpu, os.cpu_count(), mem, platform.platform())


# ---------------------------------------------------------------------------------------------------------------
# VTK flying edges (optional peer)

def analytic_numpy(name, n):
    import numpy as np
    x = np.linspace(-1, 1, n + 1)
    Z, Y, X = np.meshgrid(x, x, x, indexing="ij")  # z slowest, x fastest, like cip
    if name == "sphere":
        return np.sqrt(X * X + Y * Y + Z * Z) - 0.75, 0.0
    if name == "torus":
        q = np.hypot(X, Y) - 0.6
        return np.hypot(q, Z) - 0.25, 0.0
    if name == "gyroid":
        k = 2 * np.pi
        return (np.sin(k * X) * np.cos(k * Y) + np.sin(k * Y) * np.cos(k * Z) + np.sin(k * Z) * np.cos(k * X)), 0.0
    raise ValueError(name)


MRI = "/usr/share/mricron/templates/ch2.nii.gz"  # Colin 27 T1 (181x217x181 uint8), Debian's mricron-data
MRI_ISO = 60.0


def mri_numpy():
    """The MRI as float32 (x fastest), read with gzip and numpy: a 352-byte NIfTI-1 header, then the voxels."""
    import gzip
    import struct
    import numpy as np
    data = gzip.open(MRI).read()
    dims = struct.unpack("<8h", data[40:56])[1:4]
    offset = int(struct.unpack("<f", data[108:112])[0])
    n = dims[0] * dims[1] * dims[2]
    return np.frombuffer(data[offset:offset + n], np.uint8).astype(np.float32).reshape(dims[::-1]), MRI_ISO


def vtk_flying_edges(cases, threads_all):
    """Times vtkFlyingEdges3D on the same grids (case name, values z-y-x, isovalue). Returns rows, or a note when
    VTK is absent."""
    try:
        import numpy as np
        import vtk
        from vtk.util import numpy_support
    except ImportError:
        return [], "python3-vtk9 is not installed: VTK's flying edges were skipped."
    rows = []
    for name, values, iso in cases:
        dims = values.shape[::-1]
        img = vtk.vtkImageData()
        img.SetDimensions(*dims)
        arr = numpy_support.numpy_to_vtk(np.ascontiguousarray(values.ravel()).astype(np.float32), deep=True)
        img.GetPointData().SetScalars(arr)
        for threads in (1, threads_all):
            vtk.vtkSMPTools.Initialize(threads)
            best = None
            for _ in range(3):
                fe = vtk.vtkFlyingEdges3D()
                fe.SetInputData(img)
                fe.SetValue(0, iso)
                fe.ComputeNormalsOff()
                t0 = time.perf_counter()
                fe.Update()
                dt = time.perf_counter() - t0
                best = dt if best is None else min(best, dt)
                if dt > 1:
                    break
            cells = (dims[0] - 1) * (dims[1] - 1) * (dims[2] - 1)
            rows.append({"case": name, "points": dims[0] * dims[1] * dims[2], "cells": cells,
                         "method": "vtk-flying-edges", "threads": threads, "seconds": best,
                         "mcells_per_s": cells / best * 1e-6,
                         "output_count": fe.GetOutput().GetNumberOfCells(), "output_bytes": 0, "input_bytes": 0})
    return rows, "VTK %s flying edges (vtkSMPTools backend %s)." % (
        vtk.vtkVersion.GetVTKVersion(), vtk.vtkSMPTools.GetBackend())


def vtk_cases(extraction):
    """The grids of cip_bench's extraction cases that numpy can rebuild: analytic fields and the MRI."""
    out = []
    for case in sorted({r["case"] for r in extraction}):
        field, _, n = case.rpartition("-")
        if field in ("sphere", "torus", "gyroid") and n.isdigit():
            out.append((case,) + analytic_numpy(field, int(n)))
        elif case == "mri-colin27" and os.path.exists(MRI):
            out.append((case,) + mri_numpy())
    return out


# ---------------------------------------------------------------------------------------------------------------
# Rendering

def raycast_row(cmd, stats, case, renderer, size, spp, threads):
    """Runs raycast (whole process timed here) and turns its --stats-json into a row of the rendering table."""
    wall = timed(cmd + ["--stats-json", stats])
    s = json.load(open(stats))
    sec = s["seconds"]
    rays = s["rays"]["primary"] + s["rays"]["shadow"]
    return s, {"case": case, "renderer": renderer, "size": size, "spp": spp, "threads": s["threads"],
               "process_seconds": wall, "startup_seconds": sec.get("startup", ""),
               "scene_seconds": sec["scene_build"], "seconds": sec["render"],
               "write_seconds": sec.get("write_image", ""),
               "mrays_per_s": rays / sec["render"] * 1e-6,
               "mrays_per_s_per_core": rays / sec["render"] / s["threads"] * 1e-6,
               "primitives": s["primitives"], "hit_pixels": s["hit_pixels"]}


def render_section(build, out, quick, shared):
    """raycast on the model against raycast --mesh on the marching-cubes mesh of the same cells (and vdb_render on
    VDB inputs), same camera and size; each case at all threads and at one (scaling), and in the full run also at
    4096x4096 and at 16 samples per pixel. Returns the table's rows, a ratio table and the preview images."""
    extract = os.path.join(build, "extract", "extract")
    raycast = os.path.join(build, "raycast", "raycast")
    size = "256x256" if quick else "1024x1024"
    cores = os.cpu_count()
    cases = [("sphere-64", ["sphere", "--resolution", "64"])]
    if not quick:
        cases += [("sphere-128", ["sphere", "--resolution", "128"]), ("gyroid-64", ["gyroid", "--resolution", "64"]),
                  ("gyroid-128", ["gyroid", "--resolution", "128"])]
    vdb = os.path.join(shared, "vdb", "sphere.vdb")
    if os.path.exists(vdb):
        cases.append(("sphere.vdb", [vdb]))
    if not quick and os.path.exists(os.path.join(shared, "tooth.nhdr")):
        cases.append(("tooth", [os.path.join(shared, "tooth.nhdr"), "--iso", "120"]))
    if not quick and os.path.exists(os.path.join(shared, "headsq.nhdr")):
        cases.append(("headsq-1150", [os.path.join(shared, "headsq.nhdr"), "--iso", "1150"]))
    rows, ratio_rows, images = [], [], []
    for name, inp in cases:
        model = os.path.join(out, name + ".cip")
        mesh = os.path.join(out, name + "-mc.ply")
        sh([extract] + inp + ["-o", model, "--mc-mesh", mesh, "--quiet"])
        png = os.path.join(out, name + "-patches.png")
        s, row = raycast_row([raycast, model, "-o", os.path.join(out, name + ".exr"), "--png", png, "--size", size,
                              "--quiet"], os.path.join(out, name + "-raycast.json"), name, "raycast-patches", size, 1,
                             0)
        rows.append(row)
        cam = s["camera"]
        camera_args = ["--eye", ",".join(map(repr, cam["eye"])), "--look", ",".join(map(repr, cam["look"])),
                       "--up", ",".join(map(repr, cam["up"])), "--fov", repr(cam["fov"])]
        mpng = os.path.join(out, name + "-mc.png")
        _, mrow = raycast_row([raycast, "--mesh", mesh, "-o", os.path.join(out, name + "-mc.exr"), "--png", mpng,
                               "--size", size, "--quiet"] + camera_args, os.path.join(out, name + "-raycast-mesh.json"),
                              name, "embree-mc-mesh", size, 1, 0)
        rows.append(mrow)
        images.append((name, png, mpng))
        # Scaling: the same model and view on one thread.
        _, one = raycast_row([raycast, model, "-o", os.path.join(out, name + "-1t.exr"), "--size", size, "--quiet",
                              "--threads", "1"] + camera_args, os.path.join(out, name + "-raycast-1t.json"), name,
                             "raycast-patches", size, 1, 1)
        rows.append(one)
        ratio = {"case": name, "size": size, "patches_over_mesh_process": row["process_seconds"] / mrow["process_seconds"],
                 "patches_over_mesh_render": row["seconds"] / mrow["seconds"],
                 "startup_share": row["startup_seconds"] / row["process_seconds"] if row["startup_seconds"] != "" else "",
                 "render_speedup_1_to_%d" % cores: one["seconds"] / row["seconds"], "vdb_render_over_patches": ""}
        if name.endswith(".vdb") and shutil.which("vdb_render"):
            w, h = size.split("x")
            vout = os.path.join(out, name + "-vdb_render.exr")
            t = timed(["vdb_render", inp[0], vout, "-res", "%sx%s" % (w, h), "-translate",
                       ",".join(map(str, cam["eye"])), "-lookat", ",".join(map(str, cam["look"])), "-up",
                       ",".join(map(str, cam["up"])), "-fov", str(cam["fov"]), "-shader", "diffuse", "-cpus", "0"])
            rows.append({"case": name, "renderer": "vdb_render (whole process)", "size": size, "spp": 1,
                         "threads": cores, "process_seconds": t, "startup_seconds": "", "scene_seconds": "",
                         "seconds": "", "write_seconds": "", "mrays_per_s": int(w) * int(h) / t * 1e-6,
                         "mrays_per_s_per_core": int(w) * int(h) / t / cores * 1e-6, "primitives": "",
                         "hit_pixels": ""})
            ratio["vdb_render_over_patches"] = t / row["process_seconds"]
        ratio_rows.append(ratio)
        if not quick and name == "sphere.vdb":
            # Large images and antialiasing: 4096x4096 at one sample, 1024x1024 at 16.
            for big, spp in (("4096x4096", 1), (size, 16)):
                tag = "%s-%s-spp%d" % (name, big, spp)
                _, r = raycast_row([raycast, model, "-o", os.path.join(out, tag + ".exr"), "--size", big, "--spp",
                                    str(spp), "--quiet"] + camera_args, os.path.join(out, tag + ".json"), name,
                                   "raycast-patches", big, spp, 0)
                _, m = raycast_row([raycast, "--mesh", mesh, "-o", os.path.join(out, tag + "-mc.exr"), "--size", big,
                                    "--spp", str(spp), "--quiet"] + camera_args, os.path.join(out, tag + "-mc.json"),
                                   name, "embree-mc-mesh", big, spp, 0)
                rows += [r, m]
                ratio_rows.append({"case": name + " spp %d" % spp, "size": big,
                                   "patches_over_mesh_process": r["process_seconds"] / m["process_seconds"],
                                   "patches_over_mesh_render": r["seconds"] / m["seconds"],
                                   "startup_share": r["startup_seconds"] / r["process_seconds"],
                                   "render_speedup_1_to_%d" % cores: "", "vdb_render_over_patches": ""})
    return rows, ratio_rows, images


# ---------------------------------------------------------------------------------------------------------------
# Plots and report

def plot(fidelity, extraction, render_rows, out):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    plots = []

    def finish(fig, name):
        fig.tight_layout()
        path = os.path.join(out, name)
        fig.savefig(path, dpi=100)
        plt.close(fig)
        plots.append(path)
    fields = sorted({r["field"] for r in fidelity})
    methods = sorted({r["method"] for r in fidelity})
    for metric, label in (("dist_mean", "mean distance to the true surface (voxels)"),
                          ("normal_mean", "mean normal error (degrees)")):
        fig, axes = plt.subplots(1, len(fields), figsize=(4.5 * len(fields), 4), squeeze=False)
        for ax, field in zip(axes[0], fields):
            for m in methods:
                pts = sorted((int(r["N"]), float(r[metric])) for r in fidelity if r["field"] == field and r["method"] == m)
                if pts and all(v > 0 for _, v in pts):
                    ax.loglog([p[0] for p in pts], [p[1] for p in pts], marker="o", label=m)
            ax.set_title(field)
            ax.set_xlabel("N (cells per axis)")
            ax.set_ylabel(label)
        axes[0][0].legend(fontsize=6)
        finish(fig, "fidelity-%s.png" % metric)
    analytic = [r for r in extraction if r["case"].split("-")[0] in ("sphere", "torus", "gyroid")
                and r["case"].split("-")[-1].isdigit()]
    if analytic:
        fig, ax = plt.subplots(figsize=(6, 4))
        for m in sorted({r["method"] for r in analytic}):
            pts = sorted((int(r["case"].split("-")[-1]), float(r["seconds"])) for r in analytic
                         if r["method"] == m and r["case"].startswith("gyroid") and int(r["threads"]) == 1)
            if pts:
                ax.loglog([p[0] for p in pts], [p[1] for p in pts], marker="o", label=m)
        ax.set_title("extraction time, gyroid, 1 thread")
        ax.set_xlabel("N (cells per axis)")
        ax.set_ylabel("seconds")
        ax.legend(fontsize=7)
        finish(fig, "extraction-time.png")
    cells = {r["case"]: int(r["output_count"]) for r in extraction if r["method"] == "cip-patches-fitted"}
    one = [r for r in extraction if int(r["threads"]) == 1 and cells.get(r["case"])]
    if one:
        fig, ax = plt.subplots(figsize=(7, 4.5))
        for m in sorted({r["method"] for r in one}):
            pts = sorted((cells[r["case"]], float(r["seconds"]) / cells[r["case"]] * 1e6, r["case"])
                         for r in one if r["method"] == m)
            ax.semilogx([p[0] for p in pts], [p[1] for p in pts], marker="o", linestyle="", label=m)
            if m == "cip-patches-fitted":
                for x, y, name in pts:
                    ax.annotate(name, (x, y), fontsize=6, xytext=(3, 3), textcoords="offset points")
        ax.set_title("extraction time per patch cell, 1 thread")
        ax.set_xlabel("patch cells (crossed cells) of the case")
        ax.set_ylabel("microseconds per patch cell")
        ax.set_ylim(bottom=0)
        ax.legend(fontsize=7)
        finish(fig, "extraction-per-cell.png")
    sph = [r for r in render_rows if r["case"].startswith("sphere-") and r["threads"] != 1 and r["spp"] == 1]
    if len({r["case"] for r in sph}) > 1:
        fig, ax = plt.subplots(figsize=(6, 4))
        for rend in sorted({r["renderer"] for r in sph}):
            pts = sorted((int(r["case"].split("-")[1]), float(r["seconds"])) for r in sph if r["renderer"] == rend)
            ax.loglog([p[0] for p in pts], [p[1] for p in pts], marker="o", label=rend)
        ax.set_title("render time, analytic sphere")
        ax.set_xlabel("N (cells per axis)")
        ax.set_ylabel("seconds")
        ax.legend(fontsize=7)
        finish(fig, "render-time.png")
    return plots


def table(rows, fields, fmt=None):
    fmt = fmt or {}
    lines = ["| " + " | ".join(fields) + " |", "|" + "---|" * len(fields)]
    for r in rows:
        cells = []
        for f in fields:
            v = r.get(f, "")
            if f in fmt and v not in ("", None):
                v = fmt[f] % float(v)
            cells.append(str(v))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def ratios(extraction):
    """Extraction time of each peer divided by cip's patch model time, same case and thread count."""
    base = {(r["case"], r["threads"]): float(r["seconds"]) for r in extraction if r["method"] == "cip-patches-fitted"}
    rows = []
    for r in extraction:
        if r["method"] == "cip-patches-fitted":
            continue
        b = base.get((r["case"], r["threads"]))
        if b:
            rows.append({"case": r["case"], "threads": r["threads"], "peer": r["method"],
                         "peer_time_over_cip_fitted": float(r["seconds"]) / b})
    return rows


TARGET_CASES = ("sphere-256", "gyroid-192", "mri-colin27")


def speed_targets(extraction):
    """The figures of the extraction speed targets (docs/performance.md), per case: fitted / volumeToMesh and
    paper / flying edges on one thread, and each method's speed-up from one thread to all."""
    t = {(r["case"], r["method"], int(r["threads"])): float(r["seconds"]) for r in extraction}
    cells = {r["case"]: int(r["output_count"]) for r in extraction if r["method"] == "cip-patches-fitted"}
    n = max(int(r["threads"]) for r in extraction)
    cases = [c for c in TARGET_CASES if (c, "cip-patches-fitted", 1) in t] or sorted(cells)
    rows = []
    for c in cases:
        def ratio(a, b):
            return t[a] / t[b] if a in t and b in t else ""
        rows.append({"case": c, "patch_cells": cells.get(c, ""),
                     "fitted_s": t.get((c, "cip-patches-fitted", 1), ""),
                     "fitted_over_volumeToMesh": ratio((c, "cip-patches-fitted", 1), (c, "openvdb-volumeToMesh", 1)),
                     "paper_s": t.get((c, "cip-patches-paper", 1), ""),
                     "paper_over_flying_edges": ratio((c, "cip-patches-paper", 1), (c, "vtk-flying-edges", 1)),
                     "fitted_speedup_1_to_%d" % n: ratio((c, "cip-patches-fitted", 1), (c, "cip-patches-fitted", n)),
                     "paper_speedup_1_to_%d" % n: ratio((c, "cip-patches-paper", 1), (c, "cip-patches-paper", n)),
                     "volumeToMesh_speedup_1_to_%d" % n: ratio((c, "openvdb-volumeToMesh", 1),
                                                               (c, "openvdb-volumeToMesh", n))})
    return rows


# glibc's huge-page heap, as extract sets it for itself on inputs of 16 MB and more (extract/huge_page_restart.cpp)
HUGE_HEAP = ("glibc.malloc.hugetlb=1:glibc.malloc.mmap_threshold=33554432:glibc.malloc.trim_threshold=4294967296:"
             "glibc.malloc.top_pad=67108864")


def debian_python():
    """Re-runs this script under Debian's /usr/bin/python3 (python3-numpy/matplotlib/vtk9 live in its path) and with
    glibc's huge-page heap in the environment, so that every process timed here (cip_bench and its OpenVDB peer, VTK
    in this very process, raycast, vdb_render) runs on the same kind of heap as extract."""
    python = "/usr/bin/python3" if os.path.exists("/usr/bin/python3") else sys.executable
    heap_set = "glibc.malloc.hugetlb" in os.environ.get("GLIBC_TUNABLES", "")
    if (sys.executable == python and heap_set) or os.environ.get("CIP_BENCH_REEXEC"):
        return
    os.environ["CIP_BENCH_REEXEC"] = "1"
    if not heap_set:
        os.environ["GLIBC_TUNABLES"] = HUGE_HEAP
    os.execv(python, [python] + sys.argv)


def main():
    debian_python()
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="small sizes only (seconds per section)")
    ap.add_argument("--build-dir", default=os.path.join(ROOT, "build"), help="build directory (default: build)")
    ap.add_argument("--out", default=os.path.join(ROOT, "benchmarks", "results"), help="output folder")
    ap.add_argument("--shared-data", default=os.path.join(ROOT, "..", "shared", "data"))
    ap.add_argument("--no-install", action="store_true", help="do not install missing Debian packages")
    args = ap.parse_args()
    t_start = time.perf_counter()
    if not args.no_install:
        sh(["bash", os.path.join(ROOT, "scripts", "install-deps.sh"), "python3-numpy", "python3-matplotlib",
            "libopenvdb-tools"] + ([] if args.quick else ["python3-vtk9", "mricron-data"]), log=False)
    sh(["cmake", "-S", ROOT, "-B", args.build_dir, "-DCMAKE_BUILD_TYPE=Release", "-DCIP_BUILD_BENCHMARKS=ON"],
       log=False, stdout=subprocess.DEVNULL)
    sh(["cmake", "--build", args.build_dir, "-j", str(os.cpu_count()), "--target", "cip_bench", "extract", "raycast"],
       log=False, stdout=subprocess.DEVNULL)
    out = args.out
    os.makedirs(out, exist_ok=True)
    bench = os.path.join(args.build_dir, "benchmarks", "cip_bench")
    quick = ["--quick"] if args.quick else []
    ex_csv = os.path.join(out, "extraction.csv")
    sh([bench, "extraction", "--csv", ex_csv, "--shared-data", args.shared_data] + quick)
    extraction = read_csv(ex_csv)
    vtk_rows, vtk_note = vtk_flying_edges(vtk_cases(extraction), os.cpu_count())
    extraction += vtk_rows
    write_csv(ex_csv, extraction, list(extraction[0].keys()))

    fi_csv = os.path.join(out, "fidelity.csv")
    sh([bench, "fidelity", "--csv", fi_csv] + quick)
    fidelity = read_csv(fi_csv)

    render_rows, render_ratios, images = render_section(args.build_dir, out, args.quick, args.shared_data)
    write_csv(os.path.join(out, "rendering.csv"), render_rows, list(render_rows[0].keys()))
    write_csv(os.path.join(out, "rendering-ratios.csv"), render_ratios, list(render_ratios[0].keys()))
    ratio_rows = ratios(extraction)
    target_rows = speed_targets(extraction)
    if target_rows:
        write_csv(os.path.join(out, "extraction-targets.csv"), target_rows, list(target_rows[0].keys()))
    write_csv(os.path.join(out, "extraction-ratios.csv"), ratio_rows, list(ratio_rows[0].keys()))
    plots = plot(fidelity, extraction, render_rows, out)

    size_rows = []
    for r in extraction:
        if r["method"] == "cip-patches-fitted" and int(r["threads"]) == 1:
            mc = next(x for x in extraction if x["case"] == r["case"] and x["method"] == "cip-marching-cubes")
            size_rows.append({"case": r["case"], "input_bytes": r["input_bytes"], "model_bytes": r["output_bytes"],
                              "mc_ply_bytes": mc["output_bytes"],
                              "model_over_mc": int(r["output_bytes"]) / max(1, int(mc["output_bytes"])),
                              "model_over_input": int(r["output_bytes"]) / max(1, int(r["input_bytes"]))})
    write_csv(os.path.join(out, "size.csv"), size_rows, list(size_rows[0].keys()))

    rel = lambda p: os.path.relpath(p, out)
    md = ["# cip benchmarks" + (" (quick run)" if args.quick else ""), "",
          "Generated by `python3 benchmarks/run.py%s` in %.0f s on: %s." % (
              " --quick" if args.quick else "", time.perf_counter() - t_start, machine()), "",
          "Every figure below comes from runs made side by side in that invocation; the CSV files beside this report "
          "hold all of them. Times are the best wall-clock times of five runs; the two patch constructions run in turn (fitted, paper, fitted, ...), so that their ratio sees one machine load.",
          "", "## Extraction", "",
          "cip-patches-fitted / -paper: the corner-patch model (`buildModel`; fitted is extract's default, paper the "
          "corner I-patch paper's construction, see docs/method.md). cip-marching-cubes: the project's "
          "marching cubes (isovertices and loops, then triangulation; `extract --mc-mesh`). "
          "openvdb-volumeToMesh: OpenVDB's mesher on the same samples (all voxels active). " + vtk_note + " Times "
          "exclude reading or sampling the volume. Every process of the run (cip_bench with its OpenVDB peer, VTK in "
          "run.py's own Python, raycast, vdb_render) has glibc's huge-page heap, the GLIBC_TUNABLES that extract "
          "sets for itself on inputs of 16 MB and more (extract/huge_page_restart.cpp). mri-colin27 is the Colin 27 T1 brain template (181x217x181, uint8, "
          "Debian's mricron-data) at isovalue 60.", "",
          table(extraction, ["case", "method", "threads", "seconds", "mcells_per_s", "output_count"],
                {"seconds": "%.4f", "mcells_per_s": "%.2f"}), "",
          "Speed targets (docs/performance.md): the fitted construction against OpenVDB's volumeToMesh and the paper's "
          "against VTK's flying edges on one thread (target: at most 1.0 and 2.0), and each method's speed-up from "
          "one thread to all (target: at least 1.7 on two):", "",
          table(target_rows, list(target_rows[0].keys()) if target_rows else ["case"],
                {k: "%.2f" for k in (target_rows[0].keys() if target_rows else []) if k != "case" and k != "patch_cells"}),
          "", "![time per patch cell](extraction-per-cell.png)", "",
          "Ratios (peer time / cip-patches-fitted time, same case and threads; below 1 means the peer is faster):", "",
          table(ratio_rows, ["case", "threads", "peer", "peer_time_over_cip_fitted"],
                {"peer_time_over_cip_fitted": "%.2f"}), "",
          "## Size", "", "Model file (`.cip`) against the marching-cubes mesh (binary PLY, indexed, float positions and "
          "normals) and the input volume (analytic fields counted as float32 volumes).", "",
          table(size_rows, list(size_rows[0].keys()), {"model_over_mc": "%.2f", "model_over_input": "%.2f"}), "",
          "## Rendering", "", "raycast on the model (exact ray–patch intersection) against Embree triangles on the "
          "marching-cubes mesh of the same cells (`raycast --mesh`), same camera and image size; vdb_render (OpenVDB's "
          "level-set ray tracer) on the VDB level set with the same camera, timed as a whole process (it reports no "
          "render time). process_seconds: the whole raycast process, timed from here (one run); startup_seconds, "
          "scene_seconds (reading plus building), seconds (rendering) and write_seconds (EXR and PNG): raycast's own "
          "`--stats-json` split. mrays_per_s_per_core: rays per second of rendering divided by the threads used; "
          "each case also runs on one thread (threads = 1) for the scaling. docs/performance.md (\"Rendering\") has "
          "paired measurements; the single runs here move by 10-30 % on a shared machine.",
          "", table(render_rows, list(render_rows[0].keys()),
                    {"process_seconds": "%.3f", "startup_seconds": "%.3f", "seconds": "%.3f", "scene_seconds": "%.3f",
                     "write_seconds": "%.3f", "mrays_per_s": "%.2f", "mrays_per_s_per_core": "%.2f"}), "",
          "Ratios (whole process and render alone, patches over mesh; target: process at most 1.5; start-up share of "
          "the patch run's process, target at most 0.2; render speed-up from one thread to all; vdb_render's whole "
          "process over the patch run's, target at least 2):", "",
          table(render_ratios, list(render_ratios[0].keys()),
                {k: "%.2f" for k in render_ratios[0].keys() if k not in ("case", "size")}), ""]
    for name, a, b in images:
        md += ["%s: patches | marching-cubes mesh" % name, "", "![%s patches](%s) ![%s mc](%s)" % (
            name, rel(a), name, rel(b)), ""]
    md += ["## Fidelity", "",
           "Analytic fields sampled exactly on [-1,1]³ with N cells per axis. Samples: crossings of 4 (N ≤ 32), 3 (N = "
           "64) or 2 (N = 128) axis-aligned lines per axis per cell with the surface (same lines for patches and "
           "meshes). dist: distance to the true surface in voxels; normal: angle to the true normal in degrees; curv: "
           "|mean curvature error| × voxel size (patches only); spurious: cells whose patch has the wrong sign more "
           "than 0.5 voxel from the true surface; continuity: largest gap (voxels) and normal jump (degrees) across "
           "shared cell faces. Method names: patch-METHOD-NORMALS (the fitted rows use the reconstruction of the "
           "samples that --reconstruction auto, the default, chooses; patch-fitted-gradient-monotone and "
           "patch-fitted-gradient-central8 force one); mc-facet = marching cubes with facet normals, "
           "mc-vertexnormals-* = interpolated vertex normals; mc-exactvertices-* = marching cubes on exact edge roots.",
           "", table(fidelity, ["field", "N", "method", "dist_mean", "dist_p99", "normal_mean", "normal_p99",
                                "curv_mean", "spurious_cells", "cells", "continuity_max_gap",
                                "continuity_max_angle_deg"],
                     {"dist_mean": "%.4f", "dist_p99": "%.3f", "normal_mean": "%.2f", "normal_p99": "%.1f",
                      "curv_mean": "%.3g", "continuity_max_gap": "%.2g", "continuity_max_angle_deg": "%.2g"}), ""]
    for p in plots:
        md += ["![%s](%s)" % (os.path.basename(p), rel(p)), ""]
    md += ["## Commands", "", "```sh"] + COMMANDS + ["```", ""]
    with open(os.path.join(out, "report.md"), "w") as f:
        f.write("\n".join(md))
    print("wrote %s" % os.path.join(out, "report.md"))


if __name__ == "__main__":
    main()
