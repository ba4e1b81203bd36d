#!/usr/bin/python3
"""Peak memory of `extract` on dense volumes read whole against read slab by slab (--stream), by volume size.

A uint8 volume of n^3 voxels with four smooth blobs (a sum of Gaussians scaled to 0..255, surface at 128)
is written slice by slice as raw data with a detached NRRD header, and extracted by `extract` with
--stream off (today's whole-volume read: every sample as a double) and --stream on (slabs of about 64 MiB
of samples plus their halo), side by side in one run. The peak resident memory is the child process's own
accounting (wait4); the model's cells and bytes come from --stats-json, so the table shows what memory is
proportional to. Writes Markdown to stdout and, with --plot, a PNG (matplotlib) of peak memory against the
volume's bytes.

    /usr/bin/python3 benchmarks/streaming_memory.py [--build-dir build] [--sizes 256,512,1024]
        [--whole-max 1024] [--threads 2] [--plot benchmarks/results/streaming-memory.png]
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# Blob centres and widths as fractions of the box: the surface scales with n^2, the volume with n^3.
BLOBS = [((0.35, 0.40, 0.45), 0.16), ((0.65, 0.55, 0.50), 0.13), ((0.50, 0.70, 0.30), 0.10),
         ((0.45, 0.30, 0.70), 0.12)]


def write_volume(folder, n):
    """The blobs volume of n^3 uint8 voxels as blobs.raw + blobs.nhdr; returns the header's path."""
    raw = os.path.join(folder, "blobs-%d.raw" % n)
    axis = (np.arange(n, dtype=np.float64) + 0.5) / n
    y, x = np.meshgrid(axis, axis, indexing="ij")
    with open(raw, "wb") as f:
        for k in range(n):
            z = axis[k]
            field = np.zeros((n, n))
            for (cx, cy, cz), s in BLOBS:
                field += np.exp(-((x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2) / (2 * s * s))
            f.write(np.clip(np.rint(255 * field / 1.2), 0, 255).astype(np.uint8).tobytes())
    header = os.path.join(folder, "blobs-%d.nhdr" % n)
    with open(header, "w") as f:
        f.write("NRRD0004\ntype: uint8\ndimension: 3\nsizes: %d %d %d\nencoding: raw\nendian: little\n"
                "data file: %s\n" % (n, n, n, os.path.basename(raw)))
    return header


def run_extract(exe, path, out, mode, threads):
    """Peak resident bytes, wall seconds and the stats of one extraction."""
    stats_path = out + ".json"
    start = time.monotonic()
    proc = subprocess.Popen([exe, path, "--iso", "128", "-q", "-o", out, "--threads", str(threads),
                             "--stream", mode, "--stats-json", stats_path], stderr=subprocess.PIPE, text=True)
    _, status, usage = os.wait4(proc.pid, 0)
    err = proc.stderr.read()
    seconds = time.monotonic() - start
    if os.waitstatus_to_exitcode(status) != 0:
        sys.exit("extract --stream %s failed on %s:\n%s" % (mode, path, err))
    with open(stats_path) as f:
        stats = json.load(f)
    return usage.ru_maxrss * 1024, seconds, stats


def mib(b):
    return b / 2.0**20


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--build-dir", default=os.path.join(ROOT, "build"))
    parser.add_argument("--sizes", default="256,512,1024")
    parser.add_argument("--whole-max", type=int, default=1024, help="largest n also read whole")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--tmp", default=None, help="folder for the volumes (default: a temporary one)")
    parser.add_argument("--plot", default=None)
    args = parser.parse_args()
    exe = os.path.join(args.build_dir, "extract", "extract")
    sizes = [int(s) for s in args.sizes.split(",")]
    rows = []
    print("| volume | input bytes | mode | peak RSS MiB | peak / input | model MiB | cells | isovertices "
          "| slabs × cells | samples held MiB | seconds | same file |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory(dir=args.tmp) as tmp:
        for n in sizes:
            header = write_volume(tmp, n)
            input_bytes = n ** 3
            outputs = {}
            for mode in ("off", "on"):
                if mode == "off" and n > args.whole_max:
                    continue
                out = os.path.join(tmp, "m-%d-%s.cip" % (n, mode))
                peak, seconds, stats = run_extract(exe, header, out, mode, args.threads)
                model_bytes = stats["bytes_written"][out]
                stream = stats["stream"]
                with open(out, "rb") as f:
                    outputs[mode] = f.read()
                same = "" if mode == "off" or "off" not in outputs else (
                    "yes" if outputs["off"] == outputs["on"] else "NO")
                slabs = "%d × %d" % (stream["slabs"], stream["slab_cells"]) if stream["streamed"] else "—"
                held = "%.0f" % mib(stream["window_bytes"]) if stream["streamed"] else "%.0f" % mib(8 * n**3)
                print("| %d³ uint8 | %d | %s | %.0f | %.2f | %.1f | %d | %d | %s | %s | %.1f | %s |"
                      % (n, input_bytes, "streamed" if mode == "on" else "whole", mib(peak), peak / input_bytes,
                         mib(model_bytes), stats["model"]["non_empty_cells"], stats["model"]["isovertices"],
                         slabs, held, seconds, same), flush=True)
                rows.append((n, mode, peak, model_bytes, input_bytes))
            os.remove(header)
            os.remove(header.replace(".nhdr", ".raw"))
            for mode in outputs:
                os.remove(os.path.join(tmp, "m-%d-%s.cip" % (n, mode)))
    if args.plot:
        plot(rows, args.plot)


def plot(rows, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for mode, label, marker in (("off", "whole volume (doubles)", "s"), ("on", "streamed (slabs)", "o")):
        pts = [(r[4], r[2]) for r in rows if r[1] == mode]
        if pts:
            ax.loglog([p[0] / 2**20 for p in pts], [p[1] / 2**20 for p in pts], marker=marker, label=label)
    model = sorted({(r[4], r[3]) for r in rows if r[1] == "on"})
    ax.loglog([m[0] / 2**20 for m in model], [m[1] / 2**20 for m in model], ":", marker=".", label="model file")
    inputs = sorted({r[4] for r in rows})
    ax.loglog([i / 2**20 for i in inputs], [i / 2**20 / 4 for i in inputs], "--", color="grey",
              label="a quarter of the input")
    ax.set_xlabel("input (uint8 voxels), MiB")
    ax.set_ylabel("peak resident memory, MiB")
    ax.set_title("extract: peak memory against volume size")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
