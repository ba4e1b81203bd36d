#!/usr/bin/python3
"""Writes MetaImage test files with VTK's vtkMetaImageWriter, and reads hand-written ones with
vtkMetaImageReader, both built on ITK's MetaIO library: the truth for cip's MetaImage reader.

Usage: vtk_metaimage_files.py OUTDIR. Prints manifest lines as tests/support/nibabel_files.py describes, all of
kind "lps" (VTK's MetaImage files carry an identity TransformMatrix: the matrix is diag(spacing) plus the
origin). The samples are what vtkMetaImageReader reads back. Exits with status 3 when VTK is missing.
"""
import os
import sys
import zlib

import numpy as np

try:
    import vtk
    from vtk.util import numpy_support
except ImportError:
    sys.exit(3)

OUT = sys.argv[1]
rng = np.random.default_rng(11)
count = 0


def emit(path, spacing, origin, dims, samples):
    global count
    count += 1
    truth = os.path.join(OUT, "truth%d.f64" % count)
    with open(truth, "wb") as f:
        f.write(np.asarray(samples, dtype="<f8").tobytes())
    affine = np.eye(4)
    affine[:3, :3] = np.diag(spacing)
    affine[:3, 3] = origin
    print(path, -1, "lps", " ".join(repr(float(v)) for v in affine.ravel()), dims[0], dims[1], dims[2], truth)


def read_back(path):
    """What vtkMetaImageReader reads: spacing, origin, dims and samples (x fastest)."""
    reader = vtk.vtkMetaImageReader()
    reader.SetFileName(path)
    reader.Update()
    image = reader.GetOutput()
    samples = numpy_support.vtk_to_numpy(image.GetPointData().GetScalars())
    return image.GetSpacing(), image.GetOrigin(), image.GetDimensions(), samples


# Files written by vtkMetaImageWriter: inline and detached, plain and compressed, several sample types.
for name, compress, dtype, vtk_type in [("vtk_plain.mha", False, np.int16, vtk.VTK_SHORT),
                                        ("vtk_zlib.mha", True, np.float32, vtk.VTK_FLOAT),
                                        ("vtk_plain.mhd", False, np.uint8, vtk.VTK_UNSIGNED_CHAR),
                                        ("vtk_zlib.mhd", True, np.float64, vtk.VTK_DOUBLE),
                                        ("vtk_ushort.mha", False, np.uint16, vtk.VTK_UNSIGNED_SHORT),
                                        ("vtk_int.mhd", True, np.int32, vtk.VTK_INT)]:
    dims = (7, 5, 4)
    if np.issubdtype(dtype, np.integer):
        values = rng.integers(0, 250, int(np.prod(dims))).astype(dtype)
    else:
        values = rng.normal(size=int(np.prod(dims))).astype(dtype)
    image = vtk.vtkImageData()
    image.SetDimensions(*dims)
    image.SetSpacing(0.5, 1.25, 3.0)
    image.SetOrigin(-12.5, 40.0, 7.25)
    image.GetPointData().SetScalars(numpy_support.numpy_to_vtk(values, deep=1, array_type=vtk_type))
    writer = vtk.vtkMetaImageWriter()
    path = os.path.join(OUT, name)
    writer.SetFileName(path)
    if name.endswith(".mhd"):
        writer.SetRAWFileName(os.path.join(OUT, name[:-4] + (".zraw" if compress else ".raw")))
    writer.SetCompression(compress)
    writer.SetInputData(image)
    writer.Write()
    spacing, origin, got_dims, samples = read_back(path)
    assert tuple(got_dims) == dims and np.array_equal(samples, values)
    emit(path, spacing, origin, dims, samples)

# Hand-written files read by vtkMetaImageReader: big-endian samples, HeaderSize (bytes to skip in the data file,
# or -1: the data are at its end), ElementSize without ElementSpacing, a zlib stream after a LOCAL header.
dims = (4, 3, 5)
values = rng.integers(-3000, 3000, int(np.prod(dims))).astype(np.int16)
header = ("ObjectType = Image\nNDims = 3\nDimSize = 4 3 5\nElementSpacing = 0.75 2 1.5\nOffset = 1 -2 3\n"
          "ElementType = MET_SHORT\n")
cases = {
    "msb.mhd": (header + "BinaryDataByteOrderMSB = True\nElementDataFile = msb.raw\n",
                {"msb.raw": values.astype(">i2").tobytes()}),
    "skip.mhd": (header + "HeaderSize = 100\nElementDataFile = skip.raw\n",
                 {"skip.raw": bytes(range(100)) + values.astype("<i2").tobytes()}),
    "at_end.mhd": (header + "HeaderSize = -1\nElementDataFile = at_end.raw\n",
                   {"at_end.raw": b"some preamble of any length" + values.astype("<i2").tobytes()}),
    "zlib_local.mha": (header.replace("ElementSpacing", "ElementSize") +
                       "CompressedData = True\nElementByteOrderMSB = True\nElementDataFile = LOCAL\n", {}),
}
compressed = zlib.compress(values.astype(">i2").tobytes())
for name, (text, data_files) in cases.items():
    path = os.path.join(OUT, name)
    with open(path, "wb") as f:
        if name == "zlib_local.mha":
            text = text.replace("CompressedData = True\n",
                                "CompressedData = True\nCompressedDataSize = %d\n" % len(compressed))
        f.write(text.encode())
        if name == "zlib_local.mha":
            f.write(compressed)
    for data_name, data in data_files.items():
        with open(os.path.join(OUT, data_name), "wb") as f:
            f.write(data)
    spacing, origin, got_dims, samples = read_back(path)
    assert tuple(got_dims) == dims and np.array_equal(samples, values), name
    emit(path, spacing, origin, dims, samples)
