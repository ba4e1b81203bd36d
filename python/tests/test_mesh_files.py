"""Mesh files by extension, from the extract command and from cip.write_mesh, read back by independent readers:
meshio for PLY, STL and OBJ, and a plain parse of the glTF binary container."""
import json
import struct
import subprocess

import numpy as np
import pytest

import cip

meshio = pytest.importorskip("meshio")


def read_glb(path):
    """(positions, normals or None, faces) of the one primitive of a .glb file, parsed with struct and json."""
    data = open(path, "rb").read()
    magic, version, length = struct.unpack_from("<III", data, 0)
    assert (magic, version, length) == (0x46546C67, 2, len(data))
    json_length, json_type = struct.unpack_from("<II", data, 12)
    assert json_type == 0x4E4F534A
    doc = json.loads(data[20:20 + json_length])
    assert doc["asset"]["version"] == "2.0"
    bin_offset = 20 + json_length
    bin_length, bin_type = struct.unpack_from("<II", data, bin_offset)
    assert bin_type == 0x004E4942 and bin_length == doc["buffers"][0]["byteLength"]
    blob = data[bin_offset + 8:bin_offset + 8 + bin_length]

    def accessor(i):
        acc = doc["accessors"][i]
        view = doc["bufferViews"][acc["bufferView"]]
        dtype = {5126: np.float32, 5125: np.uint32}[acc["componentType"]]
        width = {"VEC3": 3, "SCALAR": 1}[acc["type"]]
        start = view["byteOffset"] + acc.get("byteOffset", 0)
        return np.frombuffer(blob, dtype, acc["count"] * width, start).reshape(-1, width), acc

    primitive = doc["meshes"][0]["primitives"][0]
    positions, pacc = accessor(primitive["attributes"]["POSITION"])
    np.testing.assert_array_equal(positions.min(axis=0), pacc["min"])
    np.testing.assert_array_equal(positions.max(axis=0), pacc["max"])
    normals = accessor(primitive["attributes"]["NORMAL"])[0] if "NORMAL" in primitive["attributes"] else None
    return positions, normals, accessor(primitive["indices"])[0].reshape(-1, 3)


def triangle_corners(points, faces):
    """The triangles as sorted rows of their corner coordinates (float32): comparable across vertex tables."""
    corners = np.asarray(points, np.float32)[faces].reshape(len(faces), 9)
    return corners[np.lexsort(corners.T[::-1])]


@pytest.fixture
def blobs_model(tmp_path, extract_exe, blobs_path):
    """The command writes the model and its meshes in every format; the loaded model and its meshes."""
    names = {fmt: str(tmp_path / ("mc." + fmt)) for fmt in ("ply", "stl", "obj", "glb")}
    for fmt, name in names.items():
        subprocess.run([extract_exe, blobs_path, "--iso", "128", "-o", str(tmp_path / "m.cip"), "--mc-mesh", name,
                        "--patch-mesh", str(tmp_path / ("patch." + fmt)), "--subdiv", "2", "-q"], check=True)
    model = cip.load(str(tmp_path / "m.cip"))
    return tmp_path, model.mc_mesh(), model.patch_mesh(subdiv=2)


@pytest.mark.parametrize("kind", ["mc", "patch"])
def test_command_meshes_read_back(blobs_model, kind):
    folder, mc, patch = blobs_model
    verts, faces, normals = mc if kind == "mc" else patch
    f32 = verts.astype(np.float32)
    for fmt in ("ply", "obj"):  # indexed, with normals: the same tables
        mesh = meshio.read(folder / ("%s.%s" % (kind, fmt)))
        np.testing.assert_array_equal(mesh.points.astype(np.float32), f32)
        np.testing.assert_array_equal(mesh.cells_dict["triangle"], faces)
        read_normals = mesh.point_data.get("obj:vn", mesh.point_data.get("Normals"))
        if read_normals is None:  # meshio's PLY reader names them nx, ny, nz
            read_normals = np.stack([mesh.point_data[k] for k in ("nx", "ny", "nz")], axis=1)
        np.testing.assert_array_equal(np.asarray(read_normals, np.float32), normals.astype(np.float32))
    stl = meshio.read(folder / ("%s.stl" % kind))  # unindexed: compare the triangles' corners
    np.testing.assert_array_equal(triangle_corners(stl.points, stl.cells_dict["triangle"]),
                                  triangle_corners(f32, faces))
    # The facet normals (meshio does not return them): unit, right-handed from the written corners.
    record = np.dtype([("normal", "<f4", 3), ("corners", "<f4", 9), ("attribute", "<u2")])
    facets = np.frombuffer((folder / ("%s.stl" % kind)).read_bytes(), record, offset=84)
    c = facets["corners"].astype(np.float64).reshape(-1, 3, 3)
    expected = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    length = np.linalg.norm(expected, axis=1)
    expected[length > 0] /= length[length > 0][:, None]
    np.testing.assert_array_equal(facets["normal"][length == 0], 0.0)  # degenerate triangles
    # Nearly degenerate ones turn with the rounding of their corners to float32.
    well_shaped = length > 1e-3 * np.median(length)
    np.testing.assert_allclose(facets["normal"][well_shaped], expected[well_shaped], atol=1e-2)
    positions, glb_normals, glb_faces = read_glb(folder / ("%s.glb" % kind))
    np.testing.assert_array_equal(positions, f32)
    np.testing.assert_array_equal(glb_normals, normals.astype(np.float32))
    np.testing.assert_array_equal(glb_faces, faces)


@pytest.mark.parametrize("fmt", ["ply", "stl", "obj", "glb"])
def test_write_mesh_round_trip(tmp_path, fmt):
    verts, faces, normals, _ = cip.marching_cubes(np.random.default_rng(3).random((9, 10, 11)), 0.5)
    path = str(tmp_path / ("m." + fmt))
    assert cip.write_mesh(path, verts, faces, normals) > 0
    if fmt == "glb":
        positions, read_normals, read_faces = read_glb(path)
        np.testing.assert_array_equal(positions, verts)
        np.testing.assert_array_equal(read_normals, normals)
        np.testing.assert_array_equal(read_faces, faces)
        return
    mesh = meshio.read(path)
    if fmt == "stl":
        np.testing.assert_array_equal(triangle_corners(mesh.points, mesh.cells_dict["triangle"]),
                                      triangle_corners(verts, faces))
    else:
        np.testing.assert_array_equal(mesh.points.astype(np.float32), verts)
        np.testing.assert_array_equal(mesh.cells_dict["triangle"], faces)


def test_bad_names_and_meshes(tmp_path, extract_exe, blobs_path):
    out = tmp_path / "m.cip"
    result = subprocess.run([extract_exe, blobs_path, "--iso", "128", "-o", str(out), "--mc-mesh",
                             str(tmp_path / "m.gltf")], capture_output=True, text=True)
    assert result.returncode != 0 and ".glb" in result.stderr and not out.exists()
    verts = np.zeros((3, 3))
    with pytest.raises(cip.Error, match="out of range"):
        cip.write_mesh(str(tmp_path / "x.stl"), verts, np.array([[0, 1, 3]]))
    with pytest.raises(cip.Error, match="integers"):
        cip.write_mesh(str(tmp_path / "x.stl"), verts, np.array([[0.0, 1, 2]]))
    with pytest.raises(cip.Error, match="one row per vertex"):
        cip.write_mesh(str(tmp_path / "x.obj"), verts, np.array([[0, 1, 2]]), np.zeros((2, 3)))
    assert not (tmp_path / "x.stl").exists() and not (tmp_path / "x.obj").exists()
