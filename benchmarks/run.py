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
# Size against mesh compressors, model read/write throughput

REAL_ISO = {"nucleon.nhdr": 128.0, "tooth.nhdr": 120.0, "headsq.nhdr": 500.0}  # cip_bench extraction's isovalues
DRACO = ["-qp", "14", "-qn", "10", "-cl", "7"]  # draco_encoder settings of the size table


def input_bytes(path):
    """The input's bytes on disk as cip's volumeFileBytes counts them: an NRRD detached header with its data file."""
    n = os.path.getsize(path)
    if path.endswith(".nhdr"):
        for line in open(path, errors="replace"):
            if line.lower().startswith(("data file:", "datafile:")):
                n += os.path.getsize(os.path.join(os.path.dirname(path), line.split(":", 1)[1].strip()))
    return n


def size_cases(extraction, quick, shared):
    """(case, iso, method, extract arguments, input bytes): the extraction cases (fitted, as the size table always
    had them), then the real volumes with their suggested isovalues (../shared/data/README.md), some with the
    paper construction too."""
    out = []
    for r in extraction:
        if r["method"] != "cip-patches-fitted" or int(r["threads"]) != 1:
            continue
        field, _, n = r["case"].rpartition("-")
        if field in ("sphere", "torus", "gyroid") and n.isdigit():
            out.append((r["case"], 0.0, "fitted", [field, "--resolution", n], int(r["input_bytes"])))
        elif r["case"] == "mri-colin27":
            out.append((r["case"], MRI_ISO, "fitted", [MRI, "--iso", str(MRI_ISO)], int(r["input_bytes"])))
        elif r["case"] in REAL_ISO:
            iso = REAL_ISO[r["case"]]
            out.append((r["case"], iso, "fitted", [os.path.join(shared, r["case"]), "--iso", "%g" % iso],
                        int(r["input_bytes"])))
    if quick:
        extra = [("headsq.nhdr", 500.0, ("fitted", "paper")), ("tooth.nhdr", 120.0, ("fitted",))]
    else:
        extra = [("headsq.nhdr", 500.0, ("fitted", "paper")), ("headsq.nhdr", 1150.0, ("fitted", "paper")),
                 ("tooth.nhdr", 120.0, ("fitted", "paper")), ("tooth.nhdr", 200.0, ("fitted",)),
                 ("vdb/smoke.vdb", 0.1, ("fitted", "paper"))]
    for name, iso, methods in extra:
        path = os.path.join(shared, name)
        if not os.path.exists(path):
            continue
        for m in methods:
            case = os.path.basename(name)
            if not any(c[0] == case and c[1] == iso and c[2] == m for c in out):
                out.append((case, iso, m, [path, "--iso", "%g" % iso], input_bytes(path)))
    return out


def size_section(build, out, cases, quick):
    """For each case: extract writes the model and the marching-cubes mesh of its cells (binary PLY with normals);
    the mesh is gzipped, Draco-encoded (draco_encoder) and meshoptimizer-encoded (cip_bench mesh-codecs); cip_bench
    model-io times the model's and the PLY's reading and writing. Returns (size rows, io rows, notes, versions)."""
    import gzip
    extract = os.path.join(build, "extract", "extract")
    bench = os.path.join(build, "benchmarks", "cip_bench")
    timing = ["--reps", "2"] if quick else ["--reps", "5", "--min-seconds", "0.5"]
    draco = shutil.which("draco_encoder")
    notes = [] if draco else ["draco_encoder is not installed (Debian package draco): the Draco columns are empty."]
    size_rows, io_rows = [], []
    meta = {"draco": draco_version(), "meshopt": "", "header": 0, "format": ""}
    for case, iso, method, args, in_bytes in cases:
        slug = "size-%s-%g-%s" % (case.replace(".", "_"), iso, method)
        model, mesh = os.path.join(out, slug + ".cip"), os.path.join(out, slug + "-mc.ply")
        stats_path = os.path.join(out, slug + "-extract.json")
        sh([extract] + args + ["--method", method, "-o", model, "--mc-mesh", mesh, "--stats-json", stats_path,
                               "--quiet"])
        cells = json.load(open(stats_path))["model"]["non_empty_cells"]
        model_bytes, ply_bytes = os.path.getsize(model), os.path.getsize(mesh)
        with open(mesh, "rb") as f:
            ply_gz = len(gzip.compress(f.read(), 9))
        codecs_path = os.path.join(out, slug + "-codecs.json")
        sh([bench, "mesh-codecs", "--ply", mesh, "--json", codecs_path] + timing, stdout=subprocess.DEVNULL)
        codecs = json.load(open(codecs_path))
        if not codecs["normals"]:
            notes.append("%s: the marching-cubes PLY has no normals; Draco and meshoptimizer encoded positions only."
                         % case)
        drc_bytes, drc_enc, drc_dec = "", "", ""
        if draco:
            drc = os.path.join(out, slug + "-mc.drc")
            drc_enc = draco_ms(sh([draco, "-i", mesh, "-o", drc] + DRACO, capture_output=True, text=True).stdout,
                               "encode")
            drc_bytes = os.path.getsize(drc)
            decoded = os.path.join(out, slug + "-mc-draco.ply")
            drc_dec = draco_ms(sh([draco.replace("draco_encoder", "draco_decoder"), "-i", drc, "-o", decoded],
                                  capture_output=True, text=True).stdout, "decode")
            os.remove(decoded)
        io_path = os.path.join(out, slug + "-io.json")
        sh([bench, "model-io", "--model", model, "--ply", mesh, "--json", io_path] + timing,
           stdout=subprocess.DEVNULL)
        io = json.load(open(io_path))
        mo, mz = codecs["meshopt"], codecs["meshopt_zstd"]
        v = int(codecs["meshoptimizer_version"])
        meta.update(meshopt="%d.%d" % (v // 1000, v % 1000 // 10), header=mo["header_bytes"],
                    format=io["model_file_version"])
        per = lambda b: b / cells if cells and b != "" else ""
        over = lambda b: model_bytes / b if b else ""
        size_rows.append({
            # the columns the size table always had (first, unchanged)
            "case": case, "input_bytes": in_bytes, "model_bytes": model_bytes, "mc_ply_bytes": ply_bytes,
            "model_over_mc": model_bytes / max(1, ply_bytes), "model_over_input": model_bytes / max(1, in_bytes),
            # mesh compressors on the same cells' marching-cubes mesh
            "iso": iso, "method": method, "patch_cells": cells, "mc_vertices": codecs["vertices"],
            "mc_triangles": codecs["triangles"], "model_bytes_per_cell": per(model_bytes),
            "ply_gz_bytes": ply_gz, "draco_bytes": drc_bytes, "meshopt_bytes": mo["bytes"],
            "meshopt_zstd_bytes": mz["bytes"], "meshopt_oct10_bytes": codecs["meshopt_oct10"]["bytes"],
            "ply_bytes_per_cell": per(ply_bytes), "ply_gz_bytes_per_cell": per(ply_gz),
            "draco_bytes_per_cell": per(drc_bytes), "meshopt_bytes_per_cell": per(mo["bytes"]),
            "meshopt_zstd_bytes_per_cell": per(mz["bytes"]),
            "model_over_ply_gz": over(ply_gz), "model_over_draco": over(drc_bytes),
            "model_over_meshopt": over(mo["bytes"]), "model_over_meshopt_zstd": over(mz["bytes"]),
            "draco_encode_s": drc_enc, "draco_decode_s": drc_dec, "meshopt_encode_s": mo["encode_seconds"],
            "meshopt_decode_s": mo["decode_seconds"], "meshopt_zstd_decode_s": mz["decode_seconds"],
            "meshopt_max_normal_error_deg": mo["check"]["max_normal_error_deg"]})
        for r in io["rows"]:
            row = {"case": case, "iso": iso, "method": method, "threads": r["threads"], "ply_bytes": io["ply_bytes"],
                   "model_bytes": io["model_bytes"]}
            for k in ("model_read", "model_parse", "model_serialize", "model_write", "ply_read", "ply_parse",
                      "ply_write"):
                row[k + "_mb_s"] = r["ply_mb_per_s"][k]
            row["meshopt_decode_mb_s"] = io["ply_bytes"] / mo["decode_seconds"] * 1e-6
            row["draco_decode_mb_s"] = io["ply_bytes"] / drc_dec * 1e-6 if drc_dec else ""
            row["model_read_over_ply_read_speed"] = r["seconds"]["ply_read"] / r["seconds"]["model_read"]
            for k in ("model_read", "model_write", "ply_read"):
                row[k + "_s"] = r["seconds"][k]
            io_rows.append(row)
    return size_rows, io_rows, notes, meta


def draco_ms(stdout, what):
    """Draco's own time from draco_encoder's "(444 ms to encode)" or draco_decoder's "(118 ms to decode)", in
    seconds (whole milliseconds: at least 1 ms, so that a ratio never divides by zero)."""
    import re
    m = re.search(r"\((\d+) ms to %s\)" % what, stdout)
    return max(1, int(m.group(1))) * 1e-3 if m else ""


def draco_version():
    try:
        return subprocess.run(["dpkg-query", "-W", "-f", "${Version}", "draco"], capture_output=True,
                              text=True).stdout.split("+")[0] or "(version unknown)"
    except OSError:
        return "(version unknown)"


IO_TARGET_MB_S = 200.0


def io_verdict(io_rows):
    """One sentence on the one-thread rows against the targets (model read and write >= 200 MB/s of PLY, model
    read faster than PLY read)."""
    one = [r for r in io_rows if int(r["threads"]) == 1]
    if not one:
        return ""
    count = lambda f: sum(1 for r in one if f(r))
    return ("On one thread, model read reaches %.0f MB/s of PLY in %d of %d cases, model write (serialize, write, "
            "fsync) in %d, serialize alone in %d; the model loads faster than its PLY in %d of %d." % (
                IO_TARGET_MB_S, count(lambda r: r["model_read_mb_s"] >= IO_TARGET_MB_S), len(one),
                count(lambda r: r["model_write_mb_s"] >= IO_TARGET_MB_S),
                count(lambda r: r["model_serialize_mb_s"] >= IO_TARGET_MB_S),
                count(lambda r: r["model_read_over_ply_read_speed"] > 1), len(one)))


# ---------------------------------------------------------------------------------------------------------------
# Plots and report

def holes_section(build, out, quick, shared):
    """Holes measured without trusting the construction: `extract --check-holes` (open faces where a patch takes
    the other sign than the face's corners, on a 33 x 33 lattice per face) and the topology of the crack-free patch
    mesh (--subdiv 4, the default) against the marching-cubes mesh of the same cells, both counted from the files
    (mesh_topology.py). Returns the rows."""
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from mesh_topology import mesh_topology

    extract = os.path.join(build, "extract", "extract")
    fields = [("sphere", (16,)), ("gyroid", (16,)), ("marschner-lobb", (16,))] if quick else [
        ("sphere", (16, 32, 64, 128)), ("torus", (16, 32, 64, 128)), ("gyroid", (16, 32, 64, 128)),
        ("marschner-lobb", (16, 32, 64))]
    cases = [("%s-%d" % (f, n), [f, "--resolution", str(n)]) for f, ns in fields for n in ns]
    real = [("nucleon.nhdr", 128.0), ("tooth.nhdr", 120.0)] if quick else [
        ("nucleon.nhdr", 128.0), ("tooth.nhdr", 120.0), ("tooth.nhdr", 200.0), ("headsq.nhdr", 500.0),
        ("headsq.nhdr", 1150.0), ("vdb/smoke.vdb", 0.1), ("vdb/sphere.vdb", None)]
    for name, iso in real:
        path = os.path.join(shared, name)
        if os.path.exists(path):
            cases.append(("%s%s" % (os.path.basename(name), "" if iso is None else " at %g" % iso),
                          [path] + ([] if iso is None else ["--iso", "%g" % iso])))
    rows = []
    tmp = os.path.join(out, "holes-tmp")
    os.makedirs(tmp, exist_ok=True)
    for case, args in cases:
        stats, mc, patch = (os.path.join(tmp, n) for n in ("stats.json", "mc.ply", "patch.ply"))
        cmd = [extract] + args + ["-o", os.path.join(tmp, "m.cip"), "--check-holes", "--stats-json", stats,
                                  "--mc-mesh", mc, "--patch-mesh", patch, "-q"]
        COMMANDS.append(" ".join(cmd))
        subprocess.run(cmd, check=True)
        with open(stats) as f:
            st = json.load(f)
        m, p = mesh_topology(mc), mesh_topology(patch)
        same = all(m[k] == p[k] for k in ("components", "euler")) and (m["boundary_edges"] == 0) == (
            p["boundary_edges"] == 0) and p["nonmanifold_edges"] == 0 and p["inconsistent_edges"] == 0
        rows.append({"case": case, "cells": st["model"]["non_empty_cells"],
                     "open_face_leak_cells": st["holes"]["open_face_leak_cells"],
                     "mc_components": m["components"], "mc_euler": m["euler"], "mc_boundary_edges": m["boundary_edges"],
                     "patch_components": p["components"], "patch_euler": p["euler"],
                     "patch_boundary_edges": p["boundary_edges"], "patch_nonmanifold_edges": p["nonmanifold_edges"],
                     "patch_inconsistent_edges": p["inconsistent_edges"], "topology_as_mc": "yes" if same else "no"})
    shutil.rmtree(tmp, ignore_errors=True)
    return rows


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


# glibc's huge-page heap, as extract and raycast set it for themselves on large inputs (libcip/cip/core/huge_pages.cpp)
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

    t_size = time.perf_counter()
    cases = size_cases(extraction, args.quick, args.shared_data)
    size_rows, io_rows, size_notes, size_meta = size_section(args.build_dir, out, cases, args.quick)
    print("size and model I/O sections: %.1f s" % (time.perf_counter() - t_size), file=sys.stderr)
    write_csv(os.path.join(out, "size.csv"), size_rows, list(size_rows[0].keys()))
    t_holes = time.perf_counter()
    hole_rows = holes_section(args.build_dir, out, args.quick, args.shared_data)
    print("holes section: %.1f s" % (time.perf_counter() - t_holes), file=sys.stderr)
    write_csv(os.path.join(out, "holes.csv"), hole_rows, list(hole_rows[0].keys()))
    write_csv(os.path.join(out, "model-io.csv"), io_rows, list(io_rows[0].keys()))

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
          "sets for itself on inputs of 16 MB and more and raycast on inputs of 64 KiB and more or images of 2^20 "
          "samples (libcip/cip/core/huge_pages.cpp). mri-colin27 is the Colin 27 T1 brain template (181x217x181, uint8, "
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
          "## Size", "",
          "Model file (`.cip`, format version %d) against the marching-cubes mesh of the same cells, stored plainly "
          "and through mesh compressors, and against the input volume. Each row is one `extract --method METHOD "
          "--mc-mesh` run: the model and the mesh come from the same build, the mesh's triangles lie in the model's "
          "non-empty cells, one or a few per cell (docs/meshes.md)." % size_meta["format"], "",
          "- case, iso, method: the input, the isovalue and the patch construction (fitted: extract's default; "
          "paper: the corner I-patch paper's). Analytic fields are sampled on [-1,1]³ with N cells per axis.",
          "- patch_cells: the model's non-empty cells (`extract --stats-json`, `model.non_empty_cells`); the "
          "per-cell columns divide each size by it. mc_vertices, mc_triangles: the marching-cubes mesh.",
          "- input_bytes: the volume file(s) on disk (analytic fields counted as float32 volumes). model_bytes: the "
          "`.cip` file.",
          "- mc_ply_bytes: `extract --mc-mesh` as binary little-endian PLY (float32 positions and unit normals per "
          "vertex, indexed triangles). ply_gz_bytes: that file through Python's gzip at level 9.",
          "- draco_bytes: `draco_encoder -i mesh.ply -o mesh.drc %s` (Draco %s; positions quantised to 14 bits, "
          "the PLY's normals to 10 bits, compression level 7, edgebreaker; Draco drops the triangles that "
          "quantisation makes degenerate); draco_encode_s and draco_decode_s are the times draco_encoder and "
          "draco_decoder print (whole milliseconds)." % (" ".join(DRACO), size_meta["draco"]),
          "- meshopt_bytes: `cip_bench mesh-codecs`, meshoptimizer %s as its documentation recommends: positions "
          "quantised to 16 bits per component over the mesh's bounds, normals octahedral with 8 bits per component "
          "(meshopt_encodeFilterOct), meshopt_optimizeVertexCache, vertex fetch order over both streams "
          "(meshopt_optimizeVertexFetchRemap), meshopt_encodeVertexBuffer on each stream and "
          "meshopt_encodeIndexBuffer, plus a %d-byte header (bounds, counts). meshopt_oct10_bytes: the same with "
          "10-bit normals (as Draco's). meshopt_zstd_bytes: the meshopt_bytes streams through zstd level 19. "
          "meshopt_encode_s, meshopt_decode_s: best of several runs in-process, decode to float positions, float "
          "normals and 32-bit indices (the decode is checked against the input)." % (
              size_meta["meshopt"], size_meta["header"]),
          "- model_over_X: model_bytes / X's bytes (below 1: the model is smaller); model_over_mc divides by "
          "mc_ply_bytes. size.csv also holds the Draco and meshoptimizer encode and decode times and the largest "
          "normal error of the meshoptimizer decode.", ""] + ["- " + n for n in size_notes] + (
              [""] if size_notes else []) + [
          table(size_rows, ["case", "iso", "method", "patch_cells", "mc_triangles", "input_bytes", "model_bytes",
                            "mc_ply_bytes", "ply_gz_bytes", "draco_bytes", "meshopt_bytes", "meshopt_oct10_bytes",
                            "meshopt_zstd_bytes"], {"iso": "%g"}), "",
          "Bytes per patch cell and ratios:", "",
          table(size_rows, ["case", "iso", "method", "model_bytes_per_cell", "ply_bytes_per_cell",
                            "ply_gz_bytes_per_cell", "draco_bytes_per_cell", "meshopt_bytes_per_cell",
                            "meshopt_zstd_bytes_per_cell", "model_over_mc", "model_over_ply_gz", "model_over_draco",
                            "model_over_meshopt", "model_over_meshopt_zstd", "model_over_input"],
                dict({"iso": "%g"}, **{k: "%.1f" for k in size_rows[0] if k.endswith("_per_cell")},
                     **{k: "%.2f" for k in size_rows[0] if k.startswith("model_over")})), "",
          "## Model read and write throughput", "",
          "`cip_bench model-io --model M.cip --ply MC.ply`, in-process, best of several runs, the file in the page "
          "cache, for the models and meshes of the size table. Every figure is in MB/s *of the equivalent PLY*: "
          "the bytes of the marching-cubes PLY of the same cells divided by the operation's time, so that the "
          "model and the mesh are measured against one yardstick whatever their own sizes. threads: TBB limited "
          "by tbb::global_control to one thread, then all. model_read: readModel (read the file, parse, validate); "
          "model_parse: parseModel on the bytes in memory; model_serialize: serializeModel; model_write: "
          "writeModel (serialise, write a temporary file, fsync, rename); ply_read, ply_parse, ply_write: cip's "
          "PLY reader and writer (mesh/ply.h) on the mesh, the same way. meshopt_decode_mb_s, draco_decode_mb_s: "
          "the meshoptimizer and Draco decodes of the size table (the same figure on both rows: neither is "
          "parallel). model_read_over_ply_read_speed: PLY read time / model read time (above 1: the model loads "
          "faster). Before each timed run the heap's free memory goes back to the system, as in a fresh process, "
          "so every run pays for its allocations' page faults; cip_bench runs with the huge-page heap of the whole "
          "run (see Extraction), and without it these figures are several times lower on machines where page "
          "faults are dear (virtual machines). model_write includes an fsync, whose cost depends on the disk "
          "more than on the model; model_serialize is the codec's own figure.", "",
          "Targets (issue 32): model read and write at least %.0f MB/s of equivalent PLY on one core, and a model "
          "loads faster than its mesh's PLY. %s" % (IO_TARGET_MB_S, io_verdict(io_rows)), "",
          table(io_rows, ["case", "iso", "method", "threads", "ply_bytes", "model_bytes", "model_read_mb_s",
                          "model_parse_mb_s", "model_serialize_mb_s", "model_write_mb_s", "ply_read_mb_s",
                          "ply_parse_mb_s", "ply_write_mb_s", "meshopt_decode_mb_s", "draco_decode_mb_s",
                          "model_read_over_ply_read_speed"],
                dict({"iso": "%g"}, **{k: "%.0f" for k in io_rows[0] if k.endswith("_mb_s")},
                     model_read_over_ply_read_speed="%.2f")), "",
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
    md += ["## Holes and topology", "",
           "Measured from the output files, without trusting the construction. open_face_leak_cells: cells of the "
           "stored model whose patch takes the other sign than the face's corners somewhere on an open face (a face "
           "no neighbouring patch continues; `extract --check-holes`, a 33 x 33 lattice per face with its border): "
           "where the surface leaks through a face. The crack-free patch mesh (`--patch-mesh`, subdivision 4) and the "
           "marching-cubes mesh of the same cells, read back by meshio (vertices shared by index, as written): connected components, "
           "Euler characteristic, edges used by one triangle (boundary: the surface leaves the grid, or a hole), by "
           "more than two (non-manifold), or by two running the same way (inconsistent orientation). "
           "topology_as_mc: the patch mesh has the marching-cubes mesh's components and Euler characteristic, a "
           "boundary only where it has one, and no non-manifold or inconsistent edge.", "",
           table(hole_rows, list(hole_rows[0].keys())), ""]
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
