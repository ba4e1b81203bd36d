"""cip.marching_cubes against scikit-image's: same vertices, area, orientation and normals on smooth data, for
any dtype and memory layout; errors as exceptions."""
import numpy as np
import pytest
from scipy.spatial import cKDTree

import cip
from conftest import gyroid, sphere

skimage_measure = pytest.importorskip("skimage.measure")


def area(verts, faces):
    v = verts.astype(np.float64)
    return 0.5 * np.linalg.norm(np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]]), axis=1).sum()


def face_normals(verts, faces):
    v = verts.astype(np.float64)
    return np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])


@pytest.mark.parametrize("field,level,rel_area", [(sphere, 0.5, 1e-7), (gyroid, 0.0, 1e-3)])
@pytest.mark.parametrize("spacing", [(1.0, 1.0, 1.0), (0.5, 2.0, 1.5)])
@pytest.mark.parametrize("direction", ["descent", "ascent"])
def test_matches_scikit_image(field, level, rel_area, spacing, direction):
    volume = field()
    ours = cip.marching_cubes(volume, level, spacing=spacing, gradient_direction=direction)
    theirs = skimage_measure.marching_cubes(volume, level, spacing=spacing, gradient_direction=direction)
    for a, b in zip(ours, theirs):
        assert a.dtype == b.dtype
    verts, faces, normals, values = ours
    # The same vertex set (linear edge crossings), within float32 rounding.
    assert len(verts) == len(theirs[0])
    dist, match = cKDTree(theirs[0]).query(verts)
    assert dist.max() < 1e-5 * max(spacing) * max(volume.shape)
    back, _ = cKDTree(verts).query(theirs[0])
    assert back.max() < 1e-5 * max(spacing) * max(volume.shape)
    # Area: equal where both triangulate the cells' loops alike (the sphere), else within the difference of
    # two valid triangulations of the larger loops.
    assert area(verts, faces) == pytest.approx(area(theirs[0], theirs[1]), rel=rel_area)
    # Orientation: faces wind the same way relative to the normals, and the normals agree.
    ours_sign = np.sign(np.einsum("ij,ij->i", face_normals(verts, faces), normals[faces[:, 0]]))
    theirs_sign = np.sign(np.einsum("ij,ij->i", face_normals(*theirs[:2]), theirs[2][theirs[1][:, 0]]))
    assert np.mean(ours_sign) == pytest.approx(np.mean(theirs_sign), abs=0.02)
    assert abs(np.mean(ours_sign)) > 0.9
    # scikit-image's normals are gradients in index space; cip's are world normals (the same for spacing 1).
    world = theirs[2][match] / np.asarray(spacing)
    world /= np.linalg.norm(world, axis=1)[:, None]
    assert np.mean(np.einsum("ij,ij->i", normals, world)) > 0.99
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, rtol=1e-5)
    np.testing.assert_allclose(values, theirs[3][match], rtol=1e-5)


def test_default_level_is_mid_range():
    volume = sphere()
    a = cip.marching_cubes(volume)
    b = cip.marching_cubes(volume, 0.5 * (volume.min() + volume.max()))
    np.testing.assert_array_equal(a[0], b[0])


@pytest.mark.parametrize("dtype", [np.uint8, np.int8, np.int16, np.uint16, np.int32, np.uint32, np.int64,
                                   np.uint64, np.float16, np.float32, np.float64, ">f4", "<i2"])
def test_any_numeric_dtype(dtype):
    volume = (sphere() * 40).astype(dtype)
    level = 20.5
    verts, faces, _, _ = cip.marching_cubes(volume, level)
    theirs = skimage_measure.marching_cubes(volume, level)
    assert len(verts) == len(theirs[0])
    # Integer samples make more loops of 4 to 6 corners, which the two triangulate differently.
    assert area(verts, faces) == pytest.approx(area(theirs[0], theirs[1]), rel=1e-3)


def test_layouts_give_the_same_mesh():
    volume = gyroid((30, 26, 22))
    reference = cip.marching_cubes(volume, 0.1)
    fortran = np.asfortranarray(volume)
    bigger = np.zeros((60, 26, 44))
    bigger[::2, :, ::2] = volume
    strided = bigger[::2, :, ::2]
    assert not strided.flags.c_contiguous and not strided.flags.f_contiguous
    for layout in (fortran, strided, volume.astype(np.float32)):
        ours = cip.marching_cubes(layout, 0.1)
        np.testing.assert_allclose(ours[0], reference[0], atol=1e-5)
        np.testing.assert_array_equal(ours[1], reference[1])


def test_bool_volume():
    volume = sphere() < 0.5
    verts, faces, _, _ = cip.marching_cubes(volume, 0.5)
    theirs = skimage_measure.marching_cubes(volume.astype(np.float32), 0.5)
    assert len(verts) == len(theirs[0])


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
    with pytest.raises(NotImplementedError):
        cip.marching_cubes(sphere(), 0.5, step_size=2)
    nan = sphere()
    nan[20, 16, 14] = np.nan
    with pytest.raises(cip.Error, match="NaN|non-finite|infinite"):
        cip.marching_cubes(nan, 0.5)
    flat = np.zeros((5, 5, 5))
    with pytest.raises(RuntimeError, match="No surface"):
        cip.marching_cubes(flat, 0.0)


def test_allow_degenerate_false_drops_zero_area_faces():
    volume = np.zeros((6, 6, 6))
    volume[2:4, 2:4, 2:4] = 1.0  # crossings exactly at grid points give zero-area triangles at level 1
    verts, faces, _, _ = cip.marching_cubes(volume, 0.5, allow_degenerate=False)
    v = verts.astype(np.float64)
    areas = np.linalg.norm(np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]]), axis=1)
    assert (areas > 0).all()
