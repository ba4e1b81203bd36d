#!/usr/bin/python3
"""Memory of `raycast` on models of growing size: its estimate (said before the model is read) against the peak
resident memory it then reaches, beside `raycast --mesh` on the marching-cubes mesh of the same cells.

Gyroid models at growing resolutions are extracted once (default options, their MC meshes with them); each is
rendered at 1024x1024 by `raycast` and its mesh by `raycast --mesh`, one after the other, with the same camera.
Peak resident memory is the child process's own accounting (wait4). The figures show whether the model is read
once (peak close to the decoded tables plus the scene) and how good the estimate is. Writes a Markdown table to
stdout (benchmarks/results/raycast-memory.md).

    /usr/bin/python3 benchmarks/raycast_memory.py [--build-dir build] [--resolutions 64,128,256,384]
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MIB = 1024.0 * 1024.0


def run(cmd):
    """Peak resident bytes of a child process; exits with its stderr if it fails."""
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    _, status, usage = os.wait4(proc.pid, 0)
    err = proc.stderr.read()
    if os.waitstatus_to_exitcode(status) != 0:
        sys.exit("failed: %s\n%s" % (" ".join(cmd), err))
    return usage.ru_maxrss * 1024


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--build-dir", default=os.path.join(ROOT, "build"))
    parser.add_argument("--resolutions", default="64,128,256,384")
    parser.add_argument("--size", default="1024x1024")
    parser.add_argument("--threads", default="0")
    args = parser.parse_args()
    extract = os.path.join(args.build_dir, "extract", "extract")
    raycast = os.path.join(args.build_dir, "raycast", "raycast")
    camera = ["--eye", "2.6,-3.1,2.2", "--look", "0,0,0", "--fov", "35"]
    print("| gyroid N | patch cells | model file MiB | estimate MiB | peak MiB | peak / estimate | decoded tables MiB "
          "| scene MiB | mesh triangles | mesh peak MiB | model peak / mesh peak |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for n in [int(r) for r in args.resolutions.split(",")]:
            cip = os.path.join(tmp, "g%d.cip" % n)
            ply = os.path.join(tmp, "g%d.ply" % n)
            subprocess.run([extract, "gyroid", "--resolution", str(n), "-o", cip, "--mc-mesh", ply, "--quiet"],
                           check=True)
            stats = os.path.join(tmp, "r.json")
            common = ["--size", args.size, "--threads", args.threads, "--quiet", "--stats-json", stats] + camera
            peak = run([raycast, cip, "-o", os.path.join(tmp, "m.exr")] + common)
            with open(stats) as f:
                model = json.load(f)
            memory = model["memory"]
            mesh_peak = run([raycast, "--mesh", ply, "-o", os.path.join(tmp, "t.exr")] + common)
            with open(stats) as f:
                triangles = json.load(f)["primitives"]
            estimate = memory["estimated_peak_bytes"]
            print("| %d | %d | %.2f | %.1f | %.1f | %.2f | %.1f | %.1f | %d | %.1f | %.2f |" % (
                n, model["primitives"], os.path.getsize(cip) / MIB, estimate / MIB, peak / MIB, peak / estimate,
                memory["model_bytes"] / MIB, memory["scene_bytes"] / MIB, triangles, mesh_peak / MIB,
                peak / mesh_peak), flush=True)


if __name__ == "__main__":
    main()
