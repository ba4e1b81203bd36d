"""cip.marching_cubes against scikit-image's on the same arrays: the same vertex set (within float32 rounding), the
same triangles as triples of vertex positions, the same area, normals and values, for both methods and every
keyword; smooth, integer and noisy data (the ambiguous cases and interior vertices); errors as exceptions."""
import os
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial import cKDTree

import cip
from conftest import SOURCE_DIR, gyroid, sphere

skimage_measure = pytest.importorskip("skimage.measure")


def area(verts, faces):
    v = verts.astype(np.float64)
    return 0.5 * np.linalg.norm(np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]]), axis=1).sum()


def oriented_triples(faces):
    """Each face as its cyclic rotation starting at its smallest index (keeps the winding), rows sorted."""
    first = np.argmin(faces, axis=1)
    rows = np.arange(len(faces))[:, None]
    rotated = faces[rows, (first[:, None] + np.arange(3)) % 3]
    return rotated[np.lexsort(rotated.T[::-1])]


def assert_same_mesh(ours, theirs, scale=1.0):
    """Same dtypes; a one-to-one map of vertices within float32 rounding; the same faces through it (winding
    included, duplicates counted); the same area to 1e-6; normals and values equal at mapped vertices."""
    for a, b in zip(ours, theirs):
        assert a.dtype == b.dtype and a.shape == b.shape
    verts, faces, normals, values = ours
    tol = 4 * np.finfo(np.float32).eps * scale
    dist, match = cKDTree(theirs[0]).query(verts)
    assert dist.max() <= tol
    # Duplicate positions (degenerate triangles) may map either way: compare positions, not indices, there.
    positions = np.round(theirs[0].astype(np.float64) / tol)
    keys = {tuple(p): i for i, p in enumerate(positions)}
    canonical = np.array([keys[tuple(p)] for p in positions])
    mapped = canonical[match][faces]
    assert np.array_equal(oriented_triples(mapped), oriented_triples(canonical[theirs[1]]))
    assert area(verts, faces) == pytest.approx(area(theirs[0], theirs[1]), rel=1e-6, abs=1e-12)
    # Normals and values per position (vertices at one position, if any, compared as a group).
    def per_position(keys, normals, values):
        table = np.column_stack([keys, normals, values])
        return table[np.lexsort(table.T[::-1])]

    a, b = per_position(canonical[match], normals, values), per_position(canonical, theirs[2], theirs[3])
    np.testing.assert_array_equal(a[:, 0], b[:, 0])
    np.testing.assert_allclose(a[:, 1:4], b[:, 1:4], atol=1e-6)
    np.testing.assert_allclose(a[:, 4], b[:, 4], rtol=1e-6)


def noise(shape, seed):
    return np.random.default_rng(seed).random(shape)


CASES = {
    "sphere": (lambda: sphere(), 0.5),
    "gyroid": (lambda: gyroid(), 0.0),
    "gyroid-float32": (lambda: gyroid((30, 26, 22), k=7.0).astype(np.float32), 0.2),
    "uint8": (lambda: (sphere() * 40).astype(np.uint8), 20),  # samples equal to the level: degenerate faces
    "int16": (lambda: np.round(gyroid() * 300).astype(np.int16), 7.5),
    "noise": (lambda: noise((23, 19, 21), 1), 0.5),  # every ambiguous case, interior vertices
    "2x2x2": (lambda: np.array([[[0.9, 0.1], [0.2, 0.8]], [[0.3, 0.7], [0.6, 0.05]]]), 0.5),
    "slab": (lambda: noise((30, 2, 25), 2), 0.5),
}


@pytest.mark.parametrize("name", sorted(CASES))
@pytest.mark.parametrize("method", ["lewiner", "lorensen"])
@pytest.mark.parametrize("direction", ["descent", "ascent"])
def test_matches_scikit_image(name, method, direction):
    field, level = CASES[name]
    volume = field()
    ours = cip.marching_cubes(volume, level, method=method, gradient_direction=direction)
    theirs = skimage_measure.marching_cubes(volume, level, method=method, gradient_direction=direction)
    assert_same_mesh(ours, theirs)
    # Not only the same mesh: the same order of vertices and faces, bit for bit.
    for a, b in zip(ours, theirs):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("name", ["gyroid", "noise", "uint8"])
@pytest.mark.parametrize("spacing", [(0.5, 2.0, 1.5), (1.0, 1.0, 3.0)])
def test_spacing(name, spacing):
    field, level = CASES[name]
    volume = field()
    ours = cip.marching_cubes(volume, level, spacing=spacing)
    theirs = skimage_measure.marching_cubes(volume, level, spacing=spacing)
    assert ours[0].dtype == np.float64  # scaled: float64, as scikit-image's
    assert_same_mesh(ours, theirs, scale=max(spacing) * max(volume.shape))


@pytest.mark.parametrize("name", ["sphere", "gyroid", "noise", "int16"])
@pytest.mark.parametrize("step", [2, 3])
@pytest.mark.parametrize("method", ["lewiner", "lorensen"])
def test_step_size(name, step, method):
    field, level = CASES[name]
    volume = field()
    ours = cip.marching_cubes(volume, level, step_size=step, method=method)
    theirs = skimage_measure.marching_cubes(volume, level, step_size=step, method=method)
    assert_same_mesh(ours, theirs, scale=max(volume.shape))
    assert len(ours[1]) < len(cip.marching_cubes(volume, level, method=method)[1])


@pytest.mark.parametrize("name", ["gyroid", "noise"])
def test_mask(name):
    field, level = CASES[name]
    volume = field()
    mask = np.zeros(volume.shape, dtype=bool)
    mask[2:-3, 1:, 4:] = True
    mask[5:8, 3:6, :] = False
    ours = cip.marching_cubes(volume, level, mask=mask)
    theirs = skimage_measure.marching_cubes(volume, level, mask=mask)
    assert_same_mesh(ours, theirs, scale=max(volume.shape))
    assert len(ours[1]) < len(cip.marching_cubes(volume, level)[1])


@pytest.mark.parametrize("name", ["uint8", "2x2x2", "noise"])
@pytest.mark.parametrize("spacing", [(1.0, 1.0, 1.0), (0.5, 2.0, 1.5)])
def test_allow_degenerate_false(name, spacing):
    field, level = CASES[name]
    volume = field()
    ours = cip.marching_cubes(volume, level, spacing=spacing, allow_degenerate=False)
    theirs = skimage_measure.marching_cubes(volume, level, spacing=spacing, allow_degenerate=False)
    assert_same_mesh(ours, theirs, scale=max(spacing) * max(volume.shape))
    verts, faces = ours[:2]
    v = verts.astype(np.float64)
    assert (np.linalg.norm(np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]]), axis=1) > 0).all()
    if name == "uint8":  # the data have degenerate faces, and they are gone
        assert len(faces) < len(cip.marching_cubes(volume, level, spacing=spacing)[1])


def test_the_comparison_detects_a_different_mesh():
    """The checks above can fail: a mesh with one face turned, or one vertex moved, is not accepted."""
    volume, level = CASES["noise"][0](), 0.5
    theirs = skimage_measure.marching_cubes(volume, level)
    flipped = list(cip.marching_cubes(volume, level))
    flipped[1] = flipped[1].copy()
    flipped[1][7] = flipped[1][7, ::-1]
    with pytest.raises(AssertionError):
        assert_same_mesh(flipped, theirs)
    moved = list(cip.marching_cubes(volume, level))
    moved[0] = moved[0].copy()
    moved[0][3, 1] += 1e-4
    with pytest.raises(AssertionError):
        assert_same_mesh(moved, theirs)
    lorensen = skimage_measure.marching_cubes(volume, level, method="lorensen")
    with pytest.raises(AssertionError):
        assert_same_mesh(cip.marching_cubes(volume, level), lorensen)


def test_committed_tables_are_the_installed_ones(tmp_path):
    """libcip/cip/mesh/lewiner_tables.inc is what scripts/lewiner_tables.py makes of the installed tables."""
    out = tmp_path / "tables.inc"
    subprocess.run([sys.executable, os.path.join(SOURCE_DIR, "scripts", "lewiner_tables.py"), "-o", str(out)],
                   check=True, capture_output=True)
    with open(os.path.join(SOURCE_DIR, "libcip", "cip", "mesh", "lewiner_tables.inc"), encoding="utf-8") as f:
        assert out.read_text(encoding="utf-8") == f.read()


def test_default_level_is_mid_range():
    for volume in (sphere(), gyroid().astype(np.float32), (sphere() * 40).astype(np.uint8)):
        ours = cip.marching_cubes(volume)
        theirs = skimage_measure.marching_cubes(volume)
        for a, b in zip(ours, theirs):
            np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("dtype", [bool, np.uint8, np.int8, np.int16, np.uint16, np.int32, np.uint32, np.int64,
                                   np.uint64, np.float16, np.float32, np.float64, np.longdouble, ">f4", "<i2", ">f8"])
def test_any_numeric_dtype(dtype):
    volume = (sphere() * 40).astype(dtype)
    level = 0.5 if dtype is bool else 20.5
    ours = cip.marching_cubes(volume, level)
    theirs = skimage_measure.marching_cubes(volume, level)
    for a, b in zip(ours, theirs):
        np.testing.assert_array_equal(a, b)


def test_layouts_give_the_same_mesh():
    volume = gyroid((30, 26, 22))
    reference = skimage_measure.marching_cubes(volume, 0.1)
    fortran = np.asfortranarray(volume)
    bigger = np.zeros((60, 26, 44))
    bigger[::2, :, ::2] = volume
    strided = bigger[::2, :, ::2]
    reversed_view = volume[::-1, :, ::-1][::-1, :, ::-1]
    assert not strided.flags.c_contiguous and not strided.flags.f_contiguous
    for layout in (fortran, strided, reversed_view, volume[:, ::-1, :]):
        ours = cip.marching_cubes(layout, 0.1)
        theirs = skimage_measure.marching_cubes(layout, 0.1) if layout is not fortran else reference
        for a, b in zip(ours, theirs):
            np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("name", ["gyroid", "noise", "int16"])
def test_threads_give_the_same_arrays(name):
    """Slabs walked in parallel are joined into the serial walk's arrays, bit for bit."""
    field, level = CASES[name]
    volume = np.concatenate([field()] * 3)  # enough layers for several slabs
    serial = cip.marching_cubes(volume, level, threads=1)
    for threads in (0, 2, 3):
        for a, b in zip(cip.marching_cubes(volume, level, threads=threads), serial):
            np.testing.assert_array_equal(a, b)
    for a, b in zip(serial, skimage_measure.marching_cubes(volume, level)):
        np.testing.assert_array_equal(a, b)


def test_progress_is_reported():
    fractions = []
    cip.marching_cubes(gyroid(), 0.0, progress=fractions.append)
    assert fractions and fractions[-1] == pytest.approx(1.0)
    assert all(0 <= f <= 1 for f in fractions)


def test_errors():
    with pytest.raises(ValueError, match="3-D array"):
        cip.marching_cubes(np.zeros((4, 4)), 0.5)
    with pytest.raises(ValueError, match="at least 2 samples"):
        cip.marching_cubes(np.zeros((4, 1, 4)), 0.5)
    with pytest.raises(ValueError, match="within volume data range"):
        cip.marching_cubes(sphere(), 7.0)
    with pytest.raises(TypeError, match="numeric"):
        cip.marching_cubes(sphere().astype(np.complex64), 0.5)
    with pytest.raises(ValueError, match="spacing"):
        cip.marching_cubes(sphere(), 0.5, spacing=(1, 1))
    with pytest.raises(ValueError, match="step_size"):
        cip.marching_cubes(sphere(), 0.5, step_size=0)
    with pytest.raises(ValueError, match="method"):
        cip.marching_cubes(sphere(), 0.5, method="_lorensen")
    with pytest.raises(ValueError, match="gradient_direction"):
        cip.marching_cubes(sphere(), 0.5, gradient_direction="up")
    with pytest.raises(ValueError, match="same shape"):
        cip.marching_cubes(sphere(), 0.5, mask=np.ones((3, 3, 3), dtype=bool))
    nan = sphere()
    nan[20, 16, 14] = np.nan
    with pytest.raises(cip.Error, match="NaN|non-finite|infinite"):
        cip.marching_cubes(nan, 0.5)
    with pytest.raises(RuntimeError, match="No surface"):
        cip.marching_cubes(np.zeros((5, 5, 5)), 0.0)
    with pytest.raises(RuntimeError, match="No surface"):  # no cell at this step, as scikit-image
        cip.marching_cubes(sphere((5, 5, 5)), 0.5, step_size=5)
    with pytest.raises(RuntimeError, match="No surface"):
        cip.marching_cubes(gyroid(), 0.0, mask=np.zeros(gyroid().shape, dtype=bool))
