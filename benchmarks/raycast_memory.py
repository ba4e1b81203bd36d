#!/usr/bin/python3
"""Memory of `raycast` on models of growing size: its estimate (said before the model is read) against the peak
resident memory it then reaches, beside `raycast --mesh` on the marching-cubes mesh of the same cells.

Gyroid models at growing resolutions are extracted once (default options, their MC meshes with them); each is
rendered at 1024x1024 by `raycast` and its mesh by `raycast --mesh`, one after the other, with the same camera.
Peak resident memory is the child process's own accounting (wait4). The figures show whether the model is read
once (peak close to the decoded tables plus the scene) and how good the estimate is.

With --limit SIZE (e.g. 1G) the largest model is also rendered inside a memory cgroup of that size (cgroup v1 or
v2, created when /sys/fs/cgroup is writable, i.e. as root), standing for a machine with that much memory: its
decoded tables are more than a quarter of it, and raycast must render it within the limit. Writes Markdown to
stdout (benchmarks/results/raycast-memory.md).

    /usr/bin/python3 benchmarks/raycast_memory.py [--build-dir build] [--resolutions 64,128,256,384] [--limit 1G]
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


def make_cgroup(limit_bytes):
    """A fresh memory cgroup limited to limit_bytes: (directory, procs file), or None when none can be made."""
    for root, limit_file in (("/sys/fs/cgroup/memory", "memory.limit_in_bytes"), ("/sys/fs/cgroup", "memory.max")):
        path = os.path.join(root, "cip-raycast-memory")
        try:
            os.makedirs(path, exist_ok=True)
            with open(os.path.join(path, limit_file), "w") as f:
                f.write(str(limit_bytes))
            return path, os.path.join(path, "cgroup.procs")
        except OSError:
            continue
    return None


def run_in_cgroup(procs, cmd):
    """run(cmd) with the child moved into the cgroup before it executes raycast."""
    def enter():
        with open(procs, "w") as f:
            f.write(str(os.getpid()))
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, preexec_fn=enter)
    _, status, usage = os.wait4(proc.pid, 0)
    return os.waitstatus_to_exitcode(status), usage.ru_maxrss * 1024, proc.stderr.read()


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--build-dir", default=os.path.join(ROOT, "build"))
    parser.add_argument("--resolutions", default="64,128,256,384")
    parser.add_argument("--size", default="1024x1024")
    parser.add_argument("--threads", default="0")
    parser.add_argument("--limit", default="", help="also render the largest model in a memory cgroup of this size")
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
            largest = (cip, memory, peak)
        if args.limit:
            limit = int(float(args.limit[:-1]) * 1024 ** "KMGT".index(args.limit[-1].upper()) * 1024) \
                if args.limit[-1].isalpha() else int(args.limit)
            cg = make_cgroup(limit)
            print()
            if cg is None:
                print("(no memory cgroup could be made here: the limited run was skipped)")
                return
            cip, memory, _ = largest
            status, peak, err = run_in_cgroup(cg[1], [raycast, cip, "-o", os.path.join(tmp, "l.exr"), "--size",
                                                      args.size, "--threads", args.threads] + camera)
            os.rmdir(cg[0])
            said = next((line for line in err.splitlines() if "needs about" in line), err.strip())
            print("In a memory cgroup of %s MiB: the %s model's decoded tables take %.0f MiB (%.2f of the limit); "
                  "raycast exited with status %d at a peak of %.0f MiB (%.2f of the limit). It said before reading:"
                  % (limit // (1 << 20), os.path.basename(cip), memory["model_bytes"] / MIB,
                     memory["model_bytes"] / limit, status, peak / MIB, peak / limit))
            print()
            print("    " + said)


if __name__ == "__main__":
    main()
