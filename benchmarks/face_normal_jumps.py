#!/usr/bin/env python3
"""Normals across cell faces of patch surfaces on smooth level sets: how far they jump, how far they are off.

On a tilted plane and on a large sphere (radius 48 voxels), sampled at N = 32 as signed distances, the patch
surface's points on cell faces are found by bisection along lines in the face planes (points within 1e-3 of a cell
edge left out); at each, the unit normals of the two cells sharing the face (gradients 1e-7 voxel either side)
and the true normal are compared. The G1 joins of the corner patches make the jump zero up to the finite
difference; the normal error is how far the surface itself turns. Run with Debian's Python and the built module:

    PYTHONPATH=build/python /usr/bin/python3 benchmarks/face_normal_jumps.py
"""
import numpy as np

import cip

N = 32


def measure(name, volume, true_normal):
    model = cip.extract(volume.astype(np.float32), 0.0, spacing=(1, 1, 1))
    rng = np.random.default_rng(2)
    jumps, errors = [], []
    for axis in range(3):
        a1, a2 = (axis + 1) % 3, (axis + 2) % 3
        lines = 3000
        base = np.zeros((lines, 3))
        base[:, axis] = rng.integers(2, N - 2, lines)
        base[:, a2] = rng.uniform(2, N - 2, lines)
        ts = np.linspace(2, N - 2, 4001)
        points = np.repeat(base[:, None, :], len(ts), 1)
        points[:, :, a1] = ts[None, :]
        values, _ = model.evaluate(points.reshape(-1, 3))
        values = values.reshape(lines, len(ts))
        change = (np.isfinite(values[:, :-1]) & np.isfinite(values[:, 1:]) &
                  (np.sign(values[:, :-1]) * np.sign(values[:, 1:]) < 0))
        li, ti = np.nonzero(change)
        lo, hi, vlo = points[li, ti], points[li, ti + 1], values[li, ti]
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            vm, _ = model.evaluate(mid)
            same = (np.sign(vm) == np.sign(vlo))[:, None]
            lo, hi = np.where(same, mid, lo), np.where(same, hi, mid)
        s = 0.5 * (lo + hi)
        frac = s[:, a1] - np.floor(s[:, a1])
        s = s[np.minimum(frac, 1 - frac) > 1e-3]
        step = np.zeros(3)
        step[axis] = 1e-7
        _, g1 = model.evaluate(s - step)
        _, g2 = model.evaluate(s + step)
        n1 = g1 / np.linalg.norm(g1, axis=1)[:, None]
        n2 = g2 / np.linalg.norm(g2, axis=1)[:, None]
        jumps.append(np.degrees(np.arccos(np.clip(np.sum(n1 * n2, 1), -1, 1))))
        errors.append(np.degrees(np.arccos(np.clip(np.abs(np.sum(n1 * true_normal(s), 1)), -1, 1))))
    j, e = np.concatenate(jumps), np.concatenate(errors)
    print("| %s | %d | %.2g | %.2g | %.3g | %.3g |" % (name, len(j), j.max(), j.mean(), e.max(), e.mean()))


def main():
    x = np.linspace(-1, 1, N + 1)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    n = np.array([0.3, 0.45, 0.84])
    n /= np.linalg.norm(n)
    c = np.array([0.1, -0.2, -2.5])

    def sphere_normal(s):
        w = s * 2 / N - 1 - c
        return w / np.linalg.norm(w, axis=1)[:, None]

    print("| level set (N = 32) | face-curve points | max jump (°) | mean jump (°) | max normal error (°) "
          "| mean normal error (°) |")
    print("|---|---|---|---|---|---|")
    measure("tilted plane", X * n[0] + Y * n[1] + Z * n[2] - 0.05, lambda s: np.tile(n, (len(s), 1)))
    measure("sphere of radius 48 voxels", np.sqrt((X - c[0]) ** 2 + (Y - c[1]) ** 2 + (Z - c[2]) ** 2) - 3.0,
            sphere_normal)


if __name__ == "__main__":
    main()
