"""cip.extract, cip.Model and cip.load: the same models as the extract command, meshes and field values that
agree with each other, progress, cancellation, the GIL released, and errors as exceptions."""
import os
import subprocess
import sys
import threading
import _thread
import time

import numpy as np
import pytest

import cip
from conftest import SOURCE_DIR, gyroid, sphere


def test_file_input_gives_the_commands_model(tmp_path, extract_exe, blobs_path):
    subprocess.run([extract_exe, blobs_path, "--iso", "128", "-o", str(tmp_path / "cli.cip"), "-q"], check=True)
    model = cip.extract(blobs_path, 128)
    model.save(str(tmp_path / "py.cip"))
    assert (tmp_path / "cli.cip").read_bytes() == (tmp_path / "py.cip").read_bytes()


def test_openvdb_is_loaded_only_to_read_a_vdb_file(tmp_path):
    """import cip loads no OpenVDB (its reader is a module loaded on first use); reading a .vdb file loads it."""
    source = os.path.join(SOURCE_DIR, "..", "shared", "data", "vdb", "sphere.vdb")
    if not os.path.exists(source):
        pytest.skip("no shared data beside the source tree")
    script = ("import cip\n"
              "def openvdb(): return any('libopenvdb' in line for line in open('/proc/self/maps'))\n"
              "before = openvdb()\n"
              "model = cip.extract(%r)\n"
              "print(before, openvdb(), model.n_cells)\n" % source)
    out = subprocess.run([sys.executable, "-c", script], check=True, capture_output=True, text=True).stdout.split()
    assert out[:2] == ["False", "True"]
    assert int(out[2]) > 1000


@pytest.mark.parametrize("method", ["fitted", "paper"])
def test_array_input_matches_a_raw_file(tmp_path, extract_exe, method):
    volume = np.asfortranarray((gyroid((30, 26, 22)) * 1000).astype(np.int16))  # x fastest, as raw files are
    volume.ravel(order="F").tofile(tmp_path / "v.raw")
    subprocess.run([extract_exe, str(tmp_path / "v.raw"), "--dims", "30,26,22", "--type", "int16", "--spacing",
                    "0.5,1,2", "--origin", "1,2,3", "--iso", "100", "--method", method, "-o",
                    str(tmp_path / "cli.cip"), "-q"], check=True)
    cli = cip.load(str(tmp_path / "cli.cip"))
    for layout in (volume, np.ascontiguousarray(volume)):
        model = cip.extract(layout, 100, spacing=(0.5, 1, 2), origin=(1, 2, 3), method=method)
        assert model.n_cells == cli.n_cells and model.n_vertices == cli.n_vertices
        assert model.bounds == cli.bounds
        for ours, theirs in zip(model.mc_mesh(), cli.mc_mesh()):
            np.testing.assert_array_equal(ours, theirs)


def test_model_properties_save_and_load(tmp_path):
    volume = sphere()
    model = cip.extract(volume, 0.5, spacing=(0.1, 0.2, 0.3), origin=(-1, 0, 1))
    assert model.n_cells > 100 and model.method == "fitted" and model.isovalue == 0.5
    assert model.shape == volume.shape and model.spacing == (0.1, 0.2, 0.3)
    lo, hi = model.bounds
    verts, faces, normals = model.mc_mesh()
    assert (verts >= np.array(lo) - 1e-9).all() and (verts <= np.array(hi) + 1e-9).all()
    assert faces.dtype == np.int64 and faces.max() < len(verts) and normals.shape == verts.shape
    assert model.save(str(tmp_path / "s.cip")) == os.path.getsize(tmp_path / "s.cip")
    loaded = cip.load(str(tmp_path / "s.cip"))
    assert loaded.n_cells == model.n_cells
    for a, b in zip(loaded.patch_mesh(subdiv=3), model.patch_mesh(subdiv=3)):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("method", ["fitted", "paper"])
def test_evaluate_on_the_patch_surface(method):
    model = cip.extract(gyroid((24, 24, 24)), 0.0, spacing=(0.5, 0.5, 1.0), method=method)
    # The isovertices (the marching-cubes mesh's vertices) lie on the patches, whose gradient there leans
    # the way the corner-plane normal does.
    verts, faces, normals = model.mc_mesh()
    values, gradients = model.evaluate(verts)
    scale = np.abs(gradients).max()
    assert np.abs(values).max() < 1e-9 * scale
    unit = gradients / np.linalg.norm(gradients, axis=1)[:, None]
    assert np.min(np.einsum("ij,ij->i", unit, normals)) > 0.5
    # The patch mesh's vertices found on the patches (all but those on refined edges whose owning patch has
    # no sign change, docs/meshes.md) carry the patches' exact gradients as normals.
    verts, faces, normals = model.patch_mesh(subdiv=2)
    values, gradients = model.evaluate(verts)
    length = np.linalg.norm(gradients, axis=1)
    on = (np.abs(values) < 1e-9 * scale) & (length > 1e-6 * scale)  # the few singular points left out
    assert np.mean(on) > 0.9
    unit = gradients[on] / length[on][:, None]
    assert np.min(np.einsum("ij,ij->i", unit, normals[on])) > 0.999
    # Off the surface: positive on the side above the isovalue, NaN in empty cells and outside.
    inside, _ = model.evaluate(verts[on] - 0.05 * normals[on])
    outside, _ = model.evaluate(verts[on] + 0.05 * normals[on])
    inside, outside = inside[np.isfinite(inside)], outside[np.isfinite(outside)]  # some land in empty cells
    assert len(inside) > 0.5 * np.sum(on) and len(outside) > 0.5 * np.sum(on)
    assert np.mean(inside < 0) > 0.99 and np.mean(outside > 0) > 0.99
    far, far_gradients = model.evaluate(np.array([[-100.0, 0, 0], [1e9, 1e9, 1e9]]))
    assert np.isnan(far).all() and np.isnan(far_gradients).all()


def test_progress_is_reported_from_0_to_1():
    seen = []
    cip.extract(gyroid((48, 48, 48)), 0.0, progress=seen.append)
    assert seen and seen[-1] == 1.0
    assert all(0.0 <= f <= 1.0 for f in seen) and seen == sorted(seen)


def big_volume():
    return gyroid((128, 128, 128), k=12.0).astype(np.float32)


def test_an_exception_in_progress_cancels():
    class Stop(Exception):
        pass

    def progress(fraction):
        if fraction > 0:
            raise Stop()

    with pytest.raises(Stop):
        cip.extract(big_volume(), 0.0, progress=progress)
    assert cip.extract(gyroid((20, 20, 20)), 0.0).n_cells > 0  # the library is fine afterwards


def test_ctrl_c_cancels_cleanly():
    volume = big_volume()
    start = time.monotonic()
    cip.extract(volume, 0.0)
    whole = time.monotonic() - start
    timer = threading.Timer(0.05, _thread.interrupt_main)  # what Ctrl-C does to the main thread
    timer.start()
    start = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        cip.extract(volume, 0.0)
    timer.join()
    assert time.monotonic() - start < whole + 1.0
    assert cip.extract(gyroid((20, 20, 20)), 0.0).n_cells > 0


def test_the_gil_is_released():
    volume = big_volume()
    ticks = []
    stop = threading.Event()

    def count():
        while not stop.is_set():
            ticks.append(1)
            time.sleep(0.001)

    counter = threading.Thread(target=count)
    counter.start()
    start = time.monotonic()
    cip.extract(volume, 0.0)
    elapsed = time.monotonic() - start
    stop.set()
    counter.join()
    assert elapsed > 0.1 and len(ticks) > 20 * elapsed  # a held GIL would leave the counter at 0 or 1


def test_errors(tmp_path, blobs_path):
    with pytest.raises(FileNotFoundError):
        cip.extract(str(tmp_path / "missing.nrrd"), 1.0)
    (tmp_path / "bad.nrrd").write_bytes(b"NRRD0004\ntype: float\n")
    with pytest.raises(cip.Error, match="bad.nrrd"):
        cip.extract(str(tmp_path / "bad.nrrd"), 1.0)
    with pytest.raises(cip.Error, match="level"):
        cip.extract(blobs_path)
    with pytest.raises(cip.Error, match="spacing"):
        cip.extract(blobs_path, 128, spacing=(1, 1, 1))
    with pytest.raises(cip.Error, match="3-D"):
        cip.extract(np.zeros((3, 3)), 0.5)
    with pytest.raises(cip.Error, match="method"):
        cip.extract(sphere(), 0.5, method="best")
    with pytest.raises(cip.Error, match="exact"):
        cip.extract(sphere(), 0.5, normals="exact")
    with pytest.raises(TypeError):
        cip.extract(np.array([["a"]]), 0.5)
    with pytest.raises(cip.Error):
        cip.load(str(tmp_path / "bad.nrrd"))
    nan = sphere()
    nan[20, 16, 14] = np.nan
    with pytest.raises(cip.Error, match="skip_nonfinite"):
        cip.extract(nan, 0.5)
    assert cip.extract(nan, 0.5, skip_nonfinite=True).n_cells > 0
    with pytest.warns(UserWarning, match="outside the data range"):
        assert cip.extract(sphere(), 10.0).n_cells == 0


def test_frame_of_a_series_gives_the_commands_model(tmp_path, extract_exe):
    frames = [gyroid((20, 18, 16)), sphere((20, 18, 16))]
    path = tmp_path / "series.mha"
    with open(path, "wb") as f:
        f.write(b"ObjectType = Image\nNDims = 4\nDimSize = 20 18 16 2\nElementType = MET_DOUBLE\n"
                b"TransformMatrix = 0 1 0 0  -1 0 0 0  0 0 1 0  0 0 0 1\nElementDataFile = LOCAL\n")
        for volume in frames:
            f.write(np.asarray(volume, dtype="<f8").tobytes(order="F"))
    subprocess.run([extract_exe, str(path), "--frame", "1", "--iso", "0", "-o", str(tmp_path / "cli.cip"), "-q"],
                   check=True)
    cip.extract(str(path), 0.0, frame=1).save(str(tmp_path / "py.cip"))
    assert (tmp_path / "cli.cip").read_bytes() == (tmp_path / "py.cip").read_bytes()
    assert cip.extract(str(path), 0.0, frame=0).n_cells != cip.extract(str(path), 0.0, frame=1).n_cells
    with pytest.raises(cip.Error, match="2 frames"):
        cip.extract(str(path), 0.0)


def _label_map():
    """Two touching balls (labels 2 and 5) in background 0, as uint8 (x fastest, as raw files are)."""
    x, y, z = np.meshgrid(np.arange(28), np.arange(24), np.arange(22), indexing="ij")
    volume = np.zeros((28, 24, 22), dtype=np.uint8)
    volume[(x - 9.3) ** 2 + (y - 11.6) ** 2 + (z - 10.8) ** 2 < 6.2 ** 2] = 2
    volume[(x - 17.9) ** 2 + (y - 12.2) ** 2 + (z - 11.1) ** 2 < 5.7 ** 2] = 5
    return np.asfortranarray(volume)


def test_labels_give_the_commands_models(tmp_path, extract_exe):
    volume = _label_map()
    volume.ravel(order="F").tofile(tmp_path / "labels.raw")
    subprocess.run([extract_exe, str(tmp_path / "labels.raw"), "--dims", "28,24,22", "--type", "uint8", "--labels",
                    "-o", str(tmp_path / "cli.cip"), "-q"], check=True)
    models = cip.extract_labels(volume)
    assert list(models) == [2, 5]
    for label, model in models.items():
        # The command's model of the label (the files differ only in the source named in the header), and the
        # model of one label alone.
        for other in (cip.load(str(tmp_path / ("cli-label%d.cip" % label))), cip.extract(volume, label=label)):
            assert model.n_cells == other.n_cells and model.n_vertices == other.n_vertices > 100
            for ours, theirs in zip(model.patch_mesh(subdiv=2), other.patch_mesh(subdiv=2)):
                np.testing.assert_array_equal(ours, theirs)
    # Each label's surface is closed around its own voxels: the volume it encloses is their count (voxel
    # volume 1), and its marching-cubes vertices lie on edges from a voxel of the label to one without it.
    for label, model in models.items():
        verts, faces, _ = model.patch_mesh(subdiv=2)
        tri = verts[faces]
        enclosed = abs(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum()) / 6
        assert abs(enclosed / np.count_nonzero(volume == label) - 1) < 0.1, (label, enclosed)
        mc, _, _ = model.mc_mesh()
        lo, hi = np.floor(mc).astype(int), np.ceil(mc).astype(int)
        ends = volume[tuple(lo.T)] == label, volume[tuple(hi.T)] == label
        assert (ends[0] != ends[1]).all()


def test_label_errors():
    volume = _label_map()
    with pytest.raises(cip.Error, match="level or label"):
        cip.extract(volume, 1.0, label=2)
    with pytest.raises(TypeError):
        cip.extract(volume, label="2")
    with pytest.raises(cip.Error, match="fitted"):
        cip.extract(volume, label=2, method="paper")
    with pytest.raises(cip.Error, match="integer"):
        cip.extract_labels(volume.astype(np.float32) + 0.5)
    with pytest.raises(cip.Error, match="no non-zero label"):
        cip.extract_labels(np.zeros((6, 6, 6), dtype=np.uint8))
