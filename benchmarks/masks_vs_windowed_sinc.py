#!/usr/bin/env python3
"""Masks with known truth: cip's mask reference against VTK's discrete flying edges + windowed sinc.

The VTK pipeline is 3D Slicer's default surface smoothing: vtkDiscreteFlyingEdges3D, then
vtkWindowedSincPolyDataFilter with 20 iterations, pass band 0.01, normalised coordinates, no boundary or
feature-edge smoothing, non-manifold smoothing on; normals from vtkPolyDataNormals (no splitting). cip
extracts the same uint8 mask with default options (`auto` picks the mask reference) and, for comparison,
with `--reconstruction monotone` (the samples as they are). Every surface is measured on its mesh vertices
(cip: the patch mesh, 4 samples per cell edge, normals of the patches) against the analytic shape:
distance to the true surface (voxels) and angle to the true normal (degrees). "wrong side" counts voxel
centres next to the surface that the surface puts on the other side than the mask: for cip the corners of every
crossed cell, its patch evaluated 1e-4 voxel inside the cell; for VTK the voxel centres with a neighbour on the
other side, by the mesh's signed distance (vtkImplicitPolyDataDistance).

Shapes: spheres (radius 5-40 voxels), tori and ellipsoids at random sub-voxel positions and random
rotations (fixed seed), a thin plate (1 voxel) and a thin rod (2 voxels); and a real segmentation: the CT
tooth of ../shared/data thresholded at 128, measured against cip's surface of the CT itself at that level.
Label maps: two touching half-balls labelled 1 and 2 with background 0: how far apart the two labels'
surfaces are on their shared interface (gap or overlap, voxels).

Usage: PYTHONPATH=build/python /usr/bin/python3 benchmarks/masks_vs_windowed_sinc.py [--pictures]
Writes benchmarks/results/masks.md (and, with --pictures, benchmarks/results/masks-torus-*.png rendered by
build/raycast/raycast).
"""
import argparse
import os
import subprocess
import sys
import tempfile
import time

import numpy as np
import vtk
from vtk.util import numpy_support

import cip

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OUT = os.path.join(ROOT, "benchmarks", "results")
REPORT = os.path.join(OUT, "masks.md")


# ---- shapes: signed distance (negative inside) and unit normal at the nearest surface point ----

def random_rotation(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    a, b, c, d = q
    return np.array([[a * a + b * b - c * c - d * d, 2 * (b * c - a * d), 2 * (b * d + a * c)],
                     [2 * (b * c + a * d), a * a - b * b + c * c - d * d, 2 * (c * d - a * b)],
                     [2 * (b * d - a * c), 2 * (c * d + a * b), a * a - b * b - c * c + d * d]])


class Shape:
    """A shape in its own frame, placed by rotation `rot` and centre `centre` (index coordinates)."""

    def __init__(self, name, extent, local_sdf, centre, rot):
        self.name, self.extent, self.local_sdf, self.centre, self.rot = name, extent, local_sdf, centre, rot

    def sdf(self, p):
        """Signed distance and outward unit normal at points p (N,3) in index coordinates."""
        q = (p - self.centre) @ self.rot
        d, n = self.local_sdf(q)
        return d, n @ self.rot.T


def sphere_sdf(r):
    def f(q):
        n = np.linalg.norm(q, axis=1)
        return n - r, q / np.maximum(n, 1e-12)[:, None]
    return f


def torus_sdf(big, small):
    def f(q):
        rho = np.linalg.norm(q[:, :2], axis=1)
        ring = np.stack([q[:, 0] * big / np.maximum(rho, 1e-12), q[:, 1] * big / np.maximum(rho, 1e-12),
                         0 * rho], axis=1)
        v = q - ring
        n = np.linalg.norm(v, axis=1)
        return n - small, v / np.maximum(n, 1e-12)[:, None]
    return f


def ellipsoid_sdf(axes):
    axes = np.asarray(axes, float)

    def f(q):
        # Nearest point by Newton on the Lagrange condition x_i = q_i a_i^2 / (a_i^2 + t).
        a2 = axes ** 2
        t = np.zeros(len(q))
        for _ in range(60):
            x = q * a2 / (a2 + t[:, None])
            g = np.sum((x / axes) ** 2, axis=1) - 1
            dg = -2 * np.sum(x ** 2 / (a2 * (a2 + t[:, None])), axis=1)
            t = np.maximum(t - g / dg, -a2.min() + 1e-9)
        x = q * a2 / (a2 + t[:, None])
        n = x / a2
        n /= np.linalg.norm(n, axis=1)[:, None]
        inside = np.sum((q / axes) ** 2, axis=1) < 1
        return np.where(inside, -1, 1) * np.linalg.norm(q - x, axis=1), n
    return f


def box_sdf(half):
    half = np.asarray(half, float)

    def f(q):
        d = np.abs(q) - half
        outside = np.linalg.norm(np.maximum(d, 0), axis=1)
        inside = np.minimum(d.max(axis=1), 0)
        axis = np.argmax(d, axis=1)
        n = np.zeros_like(q)
        n[np.arange(len(q)), axis] = np.sign(q[np.arange(len(q)), axis])
        return outside + inside, n
    return f


def shapes(rng):
    out = []
    for r in (5, 10, 17, 25, 40):
        out.append(Shape(f"sphere r={r}", r, sphere_sdf(r), None, np.eye(3)))
    for big, small in ((10, 4), (20, 7), (30, 12)):
        out.append(Shape(f"torus {big}/{small}", big + small, torus_sdf(big, small), None, None))
    for axes in ((12, 8, 5), (25, 15, 9), (40, 24, 14)):
        out.append(Shape("ellipsoid " + "x".join(map(str, axes)), max(axes), ellipsoid_sdf(axes), None, None))
    out.append(Shape("plate 1 voxel", 16, box_sdf((16, 16, 0.5)), None, None))
    out.append(Shape("rod 2 voxels", 16, box_sdf((16, 1.0, 1.0)), None, None))
    for s in out:
        s.rot = random_rotation(rng) if s.rot is None or not s.name.startswith("sphere") else s.rot
        n = int(2 * s.extent + 12)
        s.dims = (n, n, n)
        s.centre = np.array([n / 2.0] * 3) + rng.random(3) - 0.5
    return out


def mask_of(shape):
    idx = np.indices(shape.dims).reshape(3, -1).T.astype(float)
    d, _ = shape.sdf(idx)
    return (d < 0).reshape(shape.dims).astype(np.uint8)


# ---- meshes and measures ----

def vtk_windowed_sinc(mask):
    image = vtk.vtkImageData()
    image.SetDimensions(*mask.shape)
    # vtkImageData is x fastest; the numpy array is indexed [x, y, z], so Fortran order.
    image.GetPointData().SetScalars(numpy_support.numpy_to_vtk(mask.ravel(order="F"), deep=True))
    fe = vtk.vtkDiscreteFlyingEdges3D()
    fe.SetInputData(image)
    fe.SetValue(0, 1)
    fe.ComputeNormalsOff()
    smoother = vtk.vtkWindowedSincPolyDataFilter()
    smoother.SetInputConnection(fe.GetOutputPort())
    smoother.SetNumberOfIterations(20)
    smoother.SetPassBand(0.01)
    smoother.BoundarySmoothingOff()
    smoother.FeatureEdgeSmoothingOff()
    smoother.NonManifoldSmoothingOn()
    smoother.NormalizeCoordinatesOn()
    normals = vtk.vtkPolyDataNormals()
    normals.SetInputConnection(smoother.GetOutputPort())
    normals.SplittingOff()
    normals.ConsistencyOn()
    normals.AutoOrientNormalsOn()
    t = time.perf_counter()
    normals.Update()
    seconds = time.perf_counter() - t
    poly = normals.GetOutput()
    verts = numpy_support.vtk_to_numpy(poly.GetPoints().GetData()).astype(float)
    nrm = numpy_support.vtk_to_numpy(poly.GetPointData().GetNormals()).astype(float)
    return poly, verts, nrm, seconds


def fidelity(shape, verts, normals):
    d, n = shape.sdf(verts)
    nn = normals / np.maximum(np.linalg.norm(normals, axis=1), 1e-12)[:, None]
    cosine = np.clip(np.abs(np.sum(nn * n, axis=1)), 0, 1)
    return np.mean(np.abs(d)), np.max(np.abs(d)), np.mean(np.degrees(np.arccos(cosine)))


def band_centres(mask):
    """Voxel centres of crossed cells (a neighbour along an axis on the other side), and their sides."""
    m = mask.astype(bool)
    near = np.zeros_like(m)
    for a in range(3):
        diff = np.diff(m, axis=a)
        lo = [slice(None)] * 3
        hi = [slice(None)] * 3
        lo[a] = slice(0, -1)
        hi[a] = slice(1, None)
        near[tuple(lo)] |= diff
        near[tuple(hi)] |= diff
    idx = np.argwhere(near)
    return idx.astype(float), m[near]


def cell_corners(mask, pull=1e-4):
    """The corners of the crossed cells, each pulled 1e-4 voxel into its cell (a patch is evaluated in its own
    cell; at the corner itself every face plane through it vanishes), and the mask's side of the corner."""
    m = mask.astype(bool)
    shape = tuple(s - 1 for s in m.shape)
    anyin, allin = np.zeros(shape, bool), np.ones(shape, bool)
    for d in np.ndindex(2, 2, 2):
        s = m[d[0]:d[0] + shape[0], d[1]:d[1] + shape[1], d[2]:d[2] + shape[2]]
        anyin |= s
        allin &= s
    cells = np.argwhere(anyin & ~allin)
    pts, inside = [], []
    for d in np.ndindex(2, 2, 2):
        corner = cells + np.array(d)
        pts.append(corner + pull * (1 - 2 * np.array(d)))
        inside.append(m[corner[:, 0], corner[:, 1], corner[:, 2]])
    return np.concatenate(pts).astype(float), np.concatenate(inside)


def cip_wrong_side(model, mask):
    pts, inside = cell_corners(mask)
    values, _ = model.evaluate(pts)
    ok = np.isfinite(values)
    return int(np.sum(ok & ((values > 0) != inside)))


def vtk_wrong_side(poly, mask):
    pts, inside = band_centres(mask)
    dist = vtk.vtkImplicitPolyDataDistance()
    dist.SetInput(poly)
    signed = np.array([dist.EvaluateFunction(p) for p in pts])
    return int(np.sum((signed < 0) != inside))


def cip_surface(mask, reconstruction):
    t = time.perf_counter()
    model = cip.extract(mask, 0.5, reconstruction=reconstruction)
    seconds = time.perf_counter() - t
    verts, faces, normals = model.patch_mesh(subdiv=4)
    return model, verts, normals, seconds


# ---- label maps ----

def label_gap():
    """Two half-balls of radius 14 (labels 1 and 2) meeting on a tilted plane through the centre: how far
    label 2's surface lies from label 1's vertices on their interface (gap or overlap), in voxels."""
    rng = np.random.default_rng(7)
    n = 40
    centre = np.array([n / 2.0] * 3) + rng.random(3) - 0.5
    idx = np.indices((n, n, n)).reshape(3, -1).T.astype(float)
    q = idx - centre
    ball = np.linalg.norm(q, axis=1) < 14
    normal = np.array([0.3, 0.5, 0.81])
    normal /= np.linalg.norm(normal)
    upper = q @ normal > 0
    labels = np.where(ball, np.where(upper, 2, 1), 0).reshape(n, n, n).astype(np.uint8)
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "labels.nrrd")
        write_nrrd(path, labels)
        subprocess.run([os.path.join(ROOT, "build", "extract", "extract"), path, "--labels", "-q", "--model-version", "1", "-o",
                        os.path.join(tmp, "l.cip")], check=True)
        m1 = cip.load(os.path.join(tmp, "l-label1.cip"))
        m2 = cip.load(os.path.join(tmp, "l-label2.cip"))
    v1, _, _ = m1.patch_mesh(subdiv=4)
    v2, _, _ = m2.patch_mesh(subdiv=4)
    # Vertices of label 1 on the interface: inside label 2's cells (finite value there) and away from the
    # background (more than 2 voxels inside the ball), where only labels 1 and 2 meet.
    def apart(points, a, b):
        """How far apart the zero sets of models a and b are at points near both (first-order distances of
        each from the point, signed along the gradient: 0 when the surfaces coincide there)."""
        va, ga = a.evaluate(points)
        vb, gb = b.evaluate(points)
        ok = np.isfinite(va) & np.isfinite(vb)
        da = va[ok] / np.maximum(np.linalg.norm(ga[ok], axis=1), 1e-300)
        db = vb[ok] / np.maximum(np.linalg.norm(gb[ok], axis=1), 1e-300)
        return np.abs(da + db), int(ok.sum())

    # Label 1's vertices on the interface (where label 2's patches are), by their depth inside the ball (how
    # far the third class, the background, is).
    va, _ = m2.evaluate(v1)
    on = np.isfinite(va)
    depth = 14 - np.linalg.norm(v1 - centre, axis=1)
    bins = []
    for lo, hi in ((8, 99), (4, 8), (2, 4), (-1, 2)):
        gap, count = apart(v1[on & (depth >= lo) & (depth < hi)], m1, m2)
        bins.append((lo, hi, float(np.max(gap)) if count else float("nan"), count))
    return bins


def write_nrrd(path, array):
    with open(path, "wb") as f:
        f.write(("NRRD0004\ntype: uint8\ndimension: 3\nsizes: %d %d %d\nencoding: raw\n\n" % array.shape).encode())
        f.write(np.ascontiguousarray(array.transpose(2, 1, 0)).tobytes())


# ---- the real segmentation ----

def tooth():
    """The CT tooth thresholded at 128 (the enamel and dentine against the rest), measured against cip's
    surface of the CT itself at 128 (monotone reference): a stand-in for the truth."""
    path = os.path.join(ROOT, "..", "shared", "data", "tooth.nhdr")
    if not os.path.exists(path):
        return None
    raw = np.fromfile(os.path.join(ROOT, "..", "shared", "data", "tooth_103x94x161_uint8.raw"), np.uint8)
    ct = raw.reshape(161, 94, 103).transpose(2, 1, 0).astype(np.float64)
    mask = (ct > 128).astype(np.uint8)
    truth = cip.extract(ct, 128.0, reconstruction="monotone")
    tv, tf, _ = truth.patch_mesh(subdiv=4)
    poly = vtk.vtkPolyData()
    pts = vtk.vtkPoints()
    pts.SetData(numpy_support.numpy_to_vtk(tv, deep=True))
    poly.SetPoints(pts)
    cells = vtk.vtkCellArray()
    cells.SetCells(len(tf), numpy_support.numpy_to_vtkIdTypeArray(
        np.hstack([np.full((len(tf), 1), 3), tf]).astype(np.int64).ravel(), deep=True))
    poly.SetPolys(cells)
    dist = vtk.vtkImplicitPolyDataDistance()
    dist.SetInput(poly)

    def mean_distance(verts):
        sample = verts[:: max(1, len(verts) // 20000)]
        return np.mean([abs(dist.EvaluateFunction(p)) for p in sample])

    model, cv, _, cs = cip_surface(mask, "auto")
    vpoly, vv, _, vs = vtk_windowed_sinc(mask)
    return {"cip": mean_distance(cv), "vtk": mean_distance(vv), "cip_s": cs, "vtk_s": vs,
            "cip_wrong": cip_wrong_side(model, mask), "vtk_wrong": vtk_wrong_side(vpoly, mask),
            "reconstruction": model.reconstruction if hasattr(model, "reconstruction") else "?"}


def pictures(shape, mask):
    os.makedirs(OUT, exist_ok=True)
    raycast = os.path.join(ROOT, "build", "raycast", "raycast")
    extract = os.path.join(ROOT, "build", "extract", "extract")
    with tempfile.TemporaryDirectory() as tmp:
        nrrd = os.path.join(tmp, "mask.nrrd")
        write_nrrd(nrrd, mask)
        tag = shape.name.split()[0]
        model = os.path.join(tmp, "mask.cip")
        plain = os.path.join(tmp, "plain.cip")
        subprocess.run([extract, nrrd, "--iso", "0.5", "-q", "-o", model], check=True)
        subprocess.run([extract, nrrd, "--iso", "0.5", "-q", "--reconstruction", "monotone", "-o", plain],
                       check=True)
        poly, _, _, _ = vtk_windowed_sinc(mask)
        ply = os.path.join(tmp, "vtk.ply")
        writer = vtk.vtkPLYWriter()
        writer.SetFileName(ply)
        writer.SetInputData(poly)
        writer.SetFileTypeToBinary()
        writer.Write()
        c = shape.centre
        eye = c + np.array([0.6, -1.0, 0.7]) / np.linalg.norm([0.6, -1.0, 0.7]) * 3.2 * shape.extent
        cam = ["--eye", ",".join(map(str, eye)), "--look", ",".join(map(str, c)), "--size", "480x360", "-q"]
        for name, args in (("cip-mask", [model]), ("cip-plain", [plain]), ("vtk-windowed-sinc", ["--mesh", ply])):
            png = os.path.join(OUT, f"masks-{tag}-{name}.png")
            subprocess.run([raycast, *args, "-o", os.path.join(tmp, "x.exr"), "--png", png, *cam], check=True)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--pictures", action="store_true", help="render the torus and the tooth side by side")
    args = parser.parse_args()
    rng = np.random.default_rng(35)
    rows = []
    sums = {"cip": np.zeros(3), "vtk": np.zeros(3)}
    smooth = 0
    for shape in shapes(rng):
        mask = mask_of(shape)
        model, cv, cn, cs = cip_surface(mask, "auto")
        _, pv, pn, ps = cip_surface(mask, "monotone")
        poly, vv, vn, vs = vtk_windowed_sinc(mask)
        c, p, v = fidelity(shape, cv, cn), fidelity(shape, pv, pn), fidelity(shape, vv, vn)
        cw, vw = cip_wrong_side(model, mask), vtk_wrong_side(poly, mask)
        rows.append((shape.name, c, p, v, cw, vw, cs, ps, vs))
        if not shape.name.startswith(("plate", "rod")):
            sums["cip"] += c
            sums["vtk"] += v
            smooth += 1
        print(f"{shape.name:22s} cip {c[0]:.4f} {c[2]:5.2f}°  plain {p[0]:.4f} {p[2]:5.2f}°  "
              f"vtk {v[0]:.4f} {v[2]:5.2f}°  wrong side cip {cw} vtk {vw}  time {cs:.3f}/{ps:.3f}/{vs:.3f} s",
              flush=True)
        if args.pictures and shape.name.startswith("torus 20"):
            pictures(shape, mask)
    gaps = label_gap()
    real = tooth()
    os.makedirs(OUT, exist_ok=True)
    with open(REPORT, "w") as f:
        f.write("# Masks: cip's mask reference against VTK discrete flying edges + windowed sinc\n\n")
        f.write("Made by `benchmarks/masks_vs_windowed_sinc.py` (see its header for the method). Distances in "
                "voxels, normal errors in degrees, means over mesh vertices; max = largest vertex distance; "
                "wrong side = band voxel centres the surface puts on the wrong side; seconds in-process "
                "(cip: extract, auto; plain: extract, monotone; vtk: flying edges + smoothing + normals).\n\n")
        f.write("| shape | cip mean | cip max | cip normal | plain mean | plain normal | sinc mean | sinc max | "
                "sinc normal | wrong side cip | wrong side sinc | s cip | s plain | s sinc |\n")
        f.write("|---|" + "---|" * 13 + "\n")
        for name, c, p, v, cw, vw, cs, ps, vs in rows:
            f.write(f"| {name} | {c[0]:.4f} | {c[1]:.3f} | {c[2]:.2f} | {p[0]:.4f} | {p[2]:.2f} | {v[0]:.4f} | "
                    f"{v[1]:.3f} | {v[2]:.2f} | {cw} | {vw} | {cs:.3f} | {ps:.3f} | {vs:.3f} |\n")
        mc, mv = sums["cip"] / smooth, sums["vtk"] / smooth
        f.write(f"\nMean over the {smooth} smooth shapes: cip {mc[0]:.4f} voxel, {mc[2]:.2f}°; windowed sinc "
                f"{mv[0]:.4f} voxel, {mv[2]:.2f}° (ratio {mc[0] / mv[0]:.2f} and {mc[2] / mv[2]:.2f}).\n\n")
        f.write("Label map (two half-balls of radius 14, labels 1 and 2, background 0, `extract --labels`): how "
                "far apart the two labels' surfaces lie on their interface (largest over label 1's patch-mesh "
                "vertices there, voxels), by the vertices' depth inside the ball, i.e. their distance from the "
                "third class:\n\n| depth (voxels) | largest gap or overlap | vertices |\n|---|---|---|\n")
        for lo, hi, gap, count in gaps:
            f.write(f"| {max(lo, 0)}–{hi if hi < 99 else ''} | {gap:.2e} | {count} |\n")
        f.write("\n")
        if real:
            f.write("Real segmentation (CT tooth > 128, 103x94x161), mean distance to cip's surface of the CT "
                    f"at 128: cip {real['cip']:.4f} voxel, windowed sinc {real['vtk']:.4f}; wrong side: cip "
                    f"{real['cip_wrong']}, sinc {real['vtk_wrong']}; seconds cip {real['cip_s']:.3f}, sinc "
                    f"{real['vtk_s']:.3f}.\n")
        if args.pictures:
            f.write("\nPictures (torus 20/7, same camera): ![cip, mask reference](masks-torus-cip-mask.png) "
                    "![cip, the samples as they are](masks-torus-cip-plain.png) "
                    "![VTK flying edges + windowed sinc](masks-torus-vtk-windowed-sinc.png)\n")
    print(open(REPORT).read())


if __name__ == "__main__":
    sys.exit(main())
