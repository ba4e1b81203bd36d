"""Sparse stays sparse: an OpenVDB level set whose active voxels lie far apart in a huge index box extracts
in the memory its active voxels need, never the box's. Two spheres at opposite corners of a 4096^3 box (a
dense float grid of it would be 256 GiB) against the same two spheres side by side: the same surface, and the
same peak memory."""
import os
import subprocess

import pytest

vdb = pytest.importorskip("pyopenvdb")  # Debian's python3-openvdb


def two_spheres(path, far):
    """A level set of two spheres of radius 14 (voxel size 1): near opposite corners of [0, 4095]^3 when `far`,
    else side by side; written to `path`."""
    second = (4075.5, 4070.25, 4072.75) if far else (70.5, 65.25, 67.75)
    grid = vdb.createLevelSetSphere(radius=14.0, center=(20.5, 15.25, 17.75), voxelSize=1.0, halfWidth=3.0)
    other = vdb.createLevelSetSphere(radius=14.0, center=second, voxelSize=1.0, halfWidth=3.0)
    grid.combine(other, lambda a, b: min(a, b))
    grid.name = "surface"
    vdb.write(path, grids=[grid])
    return grid.activeVoxelCount(), grid.evalActiveVoxelBoundingBox()


def peak_extract(extract_exe, vdb_path, out_path):
    """Runs extract on the file; returns its peak resident memory in MiB (the child's own accounting)."""
    proc = subprocess.Popen([extract_exe, vdb_path, "-o", out_path, "-q", "--threads", "1"])
    _, status, usage = os.wait4(proc.pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0
    return usage.ru_maxrss / 1024.0


def test_far_apart_level_set_extracts_in_the_memory_of_its_active_voxels(tmp_path, extract_exe):
    import cip

    near_voxels, _ = two_spheres(str(tmp_path / "near.vdb"), far=False)
    far_voxels, far_box = two_spheres(str(tmp_path / "far.vdb"), far=True)
    assert far_voxels == near_voxels
    assert far_box[1][0] - far_box[0][0] > 4000  # the active voxels span the box
    near_peak = peak_extract(extract_exe, str(tmp_path / "near.vdb"), str(tmp_path / "near.cip"))
    far_peak = peak_extract(extract_exe, str(tmp_path / "far.vdb"), str(tmp_path / "far.cip"))
    print("peak resident memory: near %.1f MiB, far apart in 4096^3 %.1f MiB" % (near_peak, far_peak))
    # The same surface: the same cells, moved.
    near, far = cip.load(str(tmp_path / "near.cip")), cip.load(str(tmp_path / "far.cip"))
    assert near.n_cells == far.n_cells > 1000
    # The same memory, within what the process itself needs: nothing grows with the box (a table of one byte
    # per cell of it would be 64 GiB, one bit per brick of 8^3 voxels 16 MiB).
    assert far_peak < near_peak * 1.1 + 8, (near_peak, far_peak)
