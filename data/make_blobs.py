#!/usr/bin/python3
"""Writes blobs.nrrd: a 48^3 uint8 volume of three soft blobs and a ring (gzip NRRD), the bundled demo volume.
Values are 255 * a sum of Gaussian-like bumps, clamped; the isosurface at 128 is smooth, closed and has a hole
(the ring) and two blobs that nearly touch, so it exercises multi-loop cells. Run: python3 data/make_blobs.py"""
import gzip, math, os, struct

N = 48
def field(x, y, z):
    v = 0.0
    for (cx, cy, cz, r) in [(0.32, 0.40, 0.45, 0.16), (0.62, 0.42, 0.50, 0.13), (0.47, 0.70, 0.35, 0.10)]:
        d2 = ((x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2) / (r * r)
        v += math.exp(-0.7 * d2)
    # ring in the plane z = 0.72 around (0.5, 0.5), major radius 0.25, minor radius 0.06
    q = math.hypot(x - 0.5, y - 0.5) - 0.25
    v += math.exp(-0.7 * (q * q + (z - 0.74) ** 2) / 0.06 ** 2)
    return v

data = bytearray()
for k in range(N):
    for j in range(N):
        for i in range(N):
            x, y, z = (i + 0.5) / N, (j + 0.5) / N, (k + 0.5) / N
            data.append(max(0, min(255, int(round(255 * field(x, y, z) / 1.0)))))
header = ("NRRD0004\n# three blobs and a ring; isosurface at 128\ntype: uint8\ndimension: 3\n"
          f"sizes: {N} {N} {N}\nspace dimension: 3\nspace directions: (1,0,0) (0,1,0) (0,0,1)\n"
          "space origin: (0,0,0)\nendian: little\nencoding: gzip\n\n")
out = os.path.join(os.path.dirname(os.path.abspath(__file__)), "blobs.nrrd")
with open(out, "wb") as f:
    f.write(header.encode())
    f.write(gzip.compress(bytes(data), compresslevel=9, mtime=0))
print(out, os.path.getsize(out), "bytes")
