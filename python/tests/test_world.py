"""Surfaces where the image is: volumes with rotated, flipped and sheared index-to-world affines (written by
nibabel, an independent writer) give meshes that are scikit-image's marching cubes of the same array mapped
through nibabel's affine, with outward winding, in the file's frame or the one --space asks for."""
import json
import os
import subprocess

import numpy as np
import pytest

nib = pytest.importorskip("nibabel")
meshio = pytest.importorskip("meshio")
measure = pytest.importorskip("skimage.measure")
spatial = pytest.importorskip("scipy.spatial")

import cip


def rotation(axis, degrees):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    a = np.radians(degrees)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(a) * k + (1 - np.cos(a)) * k @ k


def blob(shape=(24, 20, 17)):
    """An off-centre ellipsoid-like field, values growing outwards: the surface is closed inside the grid."""
    i, j, k = np.meshgrid(*[np.arange(n, dtype=float) for n in shape], indexing="ij")
    return ((i - 11.3) / 8) ** 2 + ((j - 9.1) / 6.5) ** 2 + ((k - 8.2) / 5.5) ** 2 + 0.05 * np.sin(i + 2 * j)


AFFINES = {
    "identity": np.eye(4),
    # nibabel's anatomical.nii layout: x flipped, radiological
    "flip_x": np.array([[-2.0, 0, 0, 90], [0, 2, 0, -126], [0, 0, 2, -72], [0, 0, 0, 1]]),
    "rotated": np.vstack([np.hstack([rotation((1, 2, 3), 40) @ np.diag([0.9, 1.1, 1.7]), [[5], [-7], [3]]]),
                          [0, 0, 0, 1]]),
    "rotated_flipped": np.vstack([np.hstack([rotation((-1, 0.5, 2), 125) @ np.diag([1.2, -0.8, 1.0]),
                                             [[-30], [12], [44]]]), [0, 0, 0, 1]]),
    "sheared": np.array([[1.0, 0.3, 0, 1], [0, 1.2, 0.2, 2], [0.1, 0, 0.9, 3], [0, 0, 0, 1]]),
}


def write_nifti(path, data, affine):
    img = nib.Nifti1Image(data.astype(np.float32), affine)
    img.set_sform(affine, code=2)
    img.set_qform(None, code=0)
    nib.save(img, path)


def signed_volume(verts, faces):
    a, b, c = verts[faces[:, 0]], verts[faces[:, 1]], verts[faces[:, 2]]
    return np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6


def run_extract(extract_exe, path, out_dir, *extra):
    mesh = os.path.join(out_dir, "mc.ply")
    stats = os.path.join(out_dir, "stats.json")
    subprocess.run([extract_exe, path, "--iso", "1", "--method", "paper", "-o", os.path.join(out_dir, "m.cip"),
                    "--mc-mesh", mesh, "--stats-json", stats, "--quiet", *extra], check=True)
    m = meshio.read(mesh)
    with open(stats) as f:
        return m.points.astype(float), m.cells_dict["triangle"], json.load(f)


@pytest.mark.parametrize("name", sorted(AFFINES))
def test_mesh_is_scikit_image_mesh_through_the_affine(tmp_path, extract_exe, name):
    affine = AFFINES[name]
    data = blob()
    path = str(tmp_path / "v.nii.gz")
    write_nifti(path, data, affine)
    # The lossless model file (version 1) keeps the linear crossings in full precision.
    verts, faces, stats = run_extract(extract_exe, path, str(tmp_path), "--model-version", "1")

    # The stats give the file's frame and its affine.
    assert stats["world"]["space"] == "RAS"
    np.testing.assert_allclose(np.array(stats["world"]["index_to_world"]), affine, atol=1e-5)

    # Every vertex is one of scikit-image's (linear crossings of the same float32 array), mapped through
    # nibabel's affine, and the other way round.
    sk_verts, sk_faces, _, _ = measure.marching_cubes(nib.load(path).get_fdata(), 1.0)
    world = nib.affines.apply_affine(affine, sk_verts)
    scale = np.abs(world).max()
    d1, _ = spatial.cKDTree(world).query(verts)
    d2, _ = spatial.cKDTree(verts).query(world)
    assert d1.max() < 1e-5 * scale and d2.max() < 1e-5 * scale
    # The default model file (version 2) stores crossings to 1/512 of an edge (docs/model-format.md).
    v2_dir = tmp_path / "v2"
    v2_dir.mkdir()
    v2_verts, v2_faces, _ = run_extract(extract_exe, path, str(v2_dir))
    np.testing.assert_array_equal(v2_faces, faces)
    edge = np.linalg.norm(affine[:3, :3], axis=0).max()
    assert np.abs(v2_verts - verts).max() < edge / 512

    # Winding stays outward (counter-clockwise seen from outside, where the values grow) under every affine,
    # flips included: the enclosed volume is positive, and it is scikit-image's volume times |det|.
    sk_volume = abs(signed_volume(sk_verts, sk_faces)) * abs(np.linalg.det(affine[:3, :3]))
    volume = signed_volume(verts, faces)
    assert volume > 0
    assert abs(volume - sk_volume) < 1e-3 * sk_volume


def test_space_lps_negates_x_and_y(tmp_path, extract_exe):
    path = str(tmp_path / "v.nii")
    write_nifti(path, blob(), AFFINES["rotated_flipped"])
    ras_verts, ras_faces, _ = run_extract(extract_exe, path, str(tmp_path))
    lps_dir = tmp_path / "lps"
    lps_dir.mkdir()
    lps_verts, lps_faces, stats = run_extract(extract_exe, path, str(lps_dir), "--space", "lps")
    assert stats["world"]["space"] == "LPS"
    np.testing.assert_allclose(lps_verts, ras_verts * np.array([-1, -1, 1]), atol=1e-5)
    np.testing.assert_array_equal(lps_faces, ras_faces)  # a rotation by 180 degrees: winding unchanged
    las_dir = tmp_path / "las"
    las_dir.mkdir()
    las_verts, las_faces, _ = run_extract(extract_exe, path, str(las_dir), "--space", "las")
    np.testing.assert_allclose(las_verts, ras_verts * np.array([-1, 1, 1]), atol=1e-5)
    np.testing.assert_array_equal(las_faces, ras_faces[:, [0, 2, 1]])  # a flip: re-wound


def test_python_model_is_placed_like_the_file(tmp_path):
    affine = AFFINES["rotated"]
    path = str(tmp_path / "v.nii.gz")
    write_nifti(path, blob(), affine)
    model = cip.extract(path, 1.0, method="paper")
    np.testing.assert_allclose(model.affine, affine, atol=1e-5)
    assert model.world_space == "RAS"
    verts, faces, normals = model.mc_mesh()
    # Points on the surface evaluate to the isovalue, with the world gradient along the mesh normal.
    values, gradients = model.evaluate(verts)
    scale = np.abs(gradients).max()
    assert np.abs(values).max() < 1e-9 * scale
    g = gradients / np.linalg.norm(gradients, axis=1, keepdims=True)
    assert np.min(np.einsum("ij,ij->i", g, normals)) > 0.5
    lo, hi = model.bounds
    assert np.all(verts >= np.array(lo) - 1e-6) and np.all(verts <= np.array(hi) + 1e-6)
    lps, _, _ = model.mc_mesh(space="lps")
    np.testing.assert_allclose(lps, verts * np.array([-1, -1, 1]), atol=1e-9)


def test_space_without_anatomical_frame_is_an_error(tmp_path, extract_exe):
    raw = tmp_path / "v.raw"
    blob().astype(np.float32).tofile(raw)
    r = subprocess.run([extract_exe, str(raw), "--dims", "17,20,24", "--type", "float32", "--iso", "1", "-o",
                        str(tmp_path / "m.cip"), "--space", "ras", "--quiet"], capture_output=True, text=True)
    assert r.returncode != 0 and "anatomical frame" in r.stderr


def write_nrrd(path, data, affine, space="left-posterior-superior"):
    """A hand-written NRRD header with the affine's columns as space directions, data attached (x fastest)."""
    cols = affine[:3, :3].T
    header = ("NRRD0004\ntype: float\ndimension: 3\nspace: %s\nsizes: %d %d %d\n"
              "space directions: %s\nspace origin: (%r,%r,%r)\nendian: little\nencoding: raw\n\n") % (
        space, *data.shape, " ".join("(%r,%r,%r)" % tuple(c) for c in cols), *affine[:3, 3])
    with open(path, "wb") as f:
        f.write(header.encode())
        f.write(data.astype("<f4").tobytes(order="F"))


def write_metaimage(path, data, affine):
    """A hand-written MetaImage header (ITK's convention: TransformMatrix lists the direction's columns)."""
    spacing = np.linalg.norm(affine[:3, :3], axis=0)
    direction = affine[:3, :3] / spacing
    raw = os.path.basename(path)[:-4] + ".raw"
    header = ("ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n"
              "TransformMatrix = %s\nOffset = %s\nElementSpacing = %s\nDimSize = %d %d %d\n"
              "ElementType = MET_FLOAT\nElementDataFile = %s\n") % (
        " ".join(repr(v) for v in direction.T.ravel()), " ".join(repr(v) for v in affine[:3, 3]),
        " ".join(repr(v) for v in spacing), *data.shape, raw)
    with open(path, "w") as f:
        f.write(header)
    with open(os.path.join(os.path.dirname(path), raw), "wb") as f:
        f.write(data.astype("<f4").tobytes(order="F"))


@pytest.mark.parametrize("fmt", ["nrrd", "mhd"])
def test_lps_formats_place_the_mesh_through_their_affine(tmp_path, extract_exe, fmt):
    """NRRD (space directions) and MetaImage (TransformMatrix) headers written here with a rotated, flipped
    grid: the mesh is scikit-image's mapped through the header's affine, in LPS, wound outward."""
    affine = AFFINES["rotated_flipped"]
    data = blob()
    path = str(tmp_path / ("v." + fmt))
    (write_nrrd if fmt == "nrrd" else write_metaimage)(path, data, affine)
    verts, faces, stats = run_extract(extract_exe, path, str(tmp_path), "--model-version", "1")
    assert stats["world"]["space"] == "LPS"
    np.testing.assert_allclose(np.array(stats["world"]["index_to_world"]), affine, atol=1e-9)
    sk_verts, _, _, _ = measure.marching_cubes(data.astype(np.float32), 1.0)
    world = nib.affines.apply_affine(affine, sk_verts)
    d1, _ = spatial.cKDTree(world).query(verts)
    d2, _ = spatial.cKDTree(verts).query(world)
    assert max(d1.max(), d2.max()) < 1e-5 * np.abs(world).max()
    assert signed_volume(verts, faces) > 0
    ras_dir = tmp_path / "ras"
    ras_dir.mkdir()
    ras_verts, _, ras_stats = run_extract(extract_exe, path, str(ras_dir), "--model-version", "1", "--space", "ras")
    assert ras_stats["world"]["space"] == "RAS"
    np.testing.assert_allclose(ras_verts, verts * np.array([-1, -1, 1]), atol=1e-5)


def write_dicom_series(folder, data, rowcos, colcos, spacing, origin, step):
    """A DICOM CT series written with pydicom (an independent writer): slice k holds data[:, :, k] as rows j and
    columns i, int16 with RescaleSlope 0.001; files in shuffled order."""
    pydicom = pytest.importorskip("pydicom")
    from pydicom.dataset import Dataset, FileMetaDataset
    from pydicom.uid import ExplicitVRLittleEndian, generate_uid
    normal = np.cross(rowcos, colcos)
    series, study = generate_uid(), generate_uid()
    stored = np.round(data * 1000).astype(np.int16)
    order = np.random.default_rng(7).permutation(data.shape[2])
    for n, k in enumerate(order):
        meta = FileMetaDataset()
        meta.MediaStorageSOPClassUID = "1.2.840.10008.5.1.4.1.1.2"
        meta.MediaStorageSOPInstanceUID = generate_uid()
        meta.TransferSyntaxUID = ExplicitVRLittleEndian
        ds = Dataset()
        ds.file_meta = meta
        ds.SOPClassUID, ds.SOPInstanceUID = meta.MediaStorageSOPClassUID, meta.MediaStorageSOPInstanceUID
        ds.StudyInstanceUID, ds.SeriesInstanceUID, ds.Modality = study, series, "CT"
        ds.InstanceNumber = int(k) + 1
        ds.ImagePositionPatient = [float(v) for v in origin + k * step * normal]
        ds.ImageOrientationPatient = [float(v) for v in list(rowcos) + list(colcos)]
        ds.PixelSpacing = [float(spacing[1]), float(spacing[0])]  # between rows, between columns
        ds.SliceThickness = float(step)
        ds.Rows, ds.Columns = data.shape[1], data.shape[0]
        ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
        ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 16, 15, 1
        ds.RescaleSlope, ds.RescaleIntercept = 0.001, 0
        ds.PixelData = np.ascontiguousarray(stored[:, :, k].T).tobytes()
        ds.is_little_endian, ds.is_implicit_VR = True, False
        ds.save_as(os.path.join(folder, "slice%03d.dcm" % n), write_like_original=False)
    return stored * 0.001


def test_dicom_series_places_the_mesh_through_its_orientation(tmp_path, extract_exe):
    """An oblique DICOM series: the mesh is scikit-image's of the rescaled samples mapped through the series'
    own placement (columns along the row cosines, rows along the column cosines, slices along their normal), in
    LPS, wound outward."""
    rot = rotation((1, -1, 2), 25)
    rowcos, colcos = rot[:, 0], rot[:, 1]
    spacing, origin, step = np.array([0.7, 0.9]), np.array([-40.0, 12.0, 30.0]), 1.3
    folder = tmp_path / "series"
    folder.mkdir()
    values = write_dicom_series(str(folder), blob(), rowcos, colcos, spacing, origin, step)
    affine = np.eye(4)
    affine[:3, 0], affine[:3, 1] = rowcos * spacing[0], colcos * spacing[1]
    affine[:3, 2], affine[:3, 3] = np.cross(rowcos, colcos) * step, origin
    verts, faces, stats = run_extract(extract_exe, str(folder), str(tmp_path), "--model-version", "1")
    assert stats["world"]["space"] == "LPS"
    np.testing.assert_allclose(np.array(stats["world"]["index_to_world"]), affine, atol=1e-6)
    sk_verts, _, _, _ = measure.marching_cubes(values, 1.0)
    world = nib.affines.apply_affine(affine, sk_verts)
    d1, _ = spatial.cKDTree(world).query(verts)
    d2, _ = spatial.cKDTree(verts).query(world)
    assert max(d1.max(), d2.max()) < 1e-5 * np.abs(world).max()
    assert signed_volume(verts, faces) > 0
