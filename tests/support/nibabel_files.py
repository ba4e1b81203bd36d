#!/usr/bin/python3
"""Writes NIfTI test files with nibabel and, for each, the truth as nibabel reads it.

Usage: nibabel_files.py OUTDIR. Prints one manifest line per case to stdout:
  <path> <frame> <kind> <16 numbers of the 4x4 index-to-world matrix> <nx> <ny> <nz> <truth>
kind "affine": the matrix is nibabel's img.affine (RAS); kind "pixdim": the file has neither sform nor qform
and the matrix is diag(pixdim), the NIfTI standard's method 1 (nibabel's own affine for such files is its
centred Analyze guess); kind "lps": a MetaImage header written here from a nibabel affine, the matrix in
ITK's LPS world. truth: a file of float64 samples (x fastest) equal to nibabel's get_fdata() of that frame,
or "-" for a header without data. Exits with status 3 when nibabel is missing.
"""
import os
import sys

import numpy as np

try:
    import nibabel as nib
except ImportError:
    sys.exit(3)

OUT = sys.argv[1]
DATA = os.path.join(os.path.dirname(nib.__file__), "tests", "data")
rng = np.random.default_rng(7)
count = 0


def emit(path, frame, kind, affine, shape, data):
    """One manifest line; data (3-D, or None) is written as the truth file."""
    global count
    truth = "-"
    if data is not None:
        count += 1
        truth = os.path.join(OUT, "truth%d.f64" % count)
        with open(truth, "wb") as f:
            f.write(np.asarray(data, dtype="<f8").tobytes(order="F"))
    numbers = " ".join(repr(float(v)) for v in np.asarray(affine, dtype=float).ravel())
    print(path, frame, kind, numbers, shape[0], shape[1], shape[2], truth)


def emit_image(path, frames=(0,)):
    img = nib.load(path)
    hdr = img.header
    data = img.get_fdata()
    for frame in frames:
        volume = data[..., frame] if data.ndim == 4 else data
        if hdr["sform_code"] > 0 or hdr["qform_code"] > 0:
            emit(path, frame if data.ndim == 4 else -1, "affine", img.affine, volume.shape, volume)
        else:
            emit(path, frame if data.ndim == 4 else -1, "pixdim", np.diag(list(hdr.get_zooms()[:3]) + [1]),
                 volume.shape, volume)


def rotation(ax, ay, az):
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


def affine(linear, offset):
    a = np.eye(4)
    a[:3, :3] = linear
    a[:3, 3] = offset
    return a


def volume(shape, dtype):
    if np.issubdtype(dtype, np.integer):
        return rng.integers(-100 if np.issubdtype(dtype, np.signedinteger) else 0, 200, shape).astype(dtype)
    return rng.normal(size=shape).astype(dtype)


# nibabel's own test files.
for name, frames in [("anatomical.nii", (0,)), ("example4d.nii.gz", (0, 1)), ("example_nifti2.nii.gz", (1,)),
                     ("functional.nii", (0, 7, 19)), ("reoriented_anat_moved.nii", (0,)),
                     ("resampled_anat_moved.nii", (0,)), ("standard.nii.gz", (0,))]:
    emit_image(os.path.join(DATA, name), frames)
for name in ("nifti1.hdr", "nifti2.hdr"):  # headers shipped without their .img
    img = nib.load(os.path.join(DATA, name))
    emit(os.path.join(DATA, name), -1, "affine", img.affine, img.shape, None)

rotated = affine(rotation(0.3, -0.5, 1.1) @ np.diag([0.7, 1.3, 2.1]), [-40.5, 12.25, 7.0])
flipped = affine(rotation(-0.2, 0.4, 2.5) @ np.diag([1.5, 0.8, -1.1]), [3.0, -20.0, 55.5])  # det < 0: qfac -1
sheared = affine(np.array([[1.2, 0.3, 0.0], [0.0, 0.9, -0.4], [0.25, 0.0, 1.6]]), [1.0, 2.0, 3.0])
half_turn = affine(rotation(np.pi, 0, 0) @ np.diag([1.0, 2.0, 3.0]), [10.0, 20.0, 30.0])  # quaternion a = 0

cases = []
# Rotated, sform and qform both set (sform code 2, qform code 1).
img = nib.Nifti1Image(volume((7, 6, 5), np.int16), rotated)
img.set_qform(rotated, code=1)
cases.append(("rotated.nii", img))
# qform only, with a flipped third axis: qfac = -1.
img = nib.Nifti1Image(volume((5, 7, 6), np.float32), None)
img.set_qform(flipped, code=1)
img.set_sform(None, code=0)
cases.append(("qform_flip.nii", img))
# A 180-degree rotation: the quaternion's a is 0.
img = nib.Nifti1Image(volume((4, 5, 6), np.uint8), None)
img.set_qform(half_turn, code=2)
img.set_sform(None, code=0)
cases.append(("half_turn.nii.gz", img))
# Sheared sform only.
img = nib.Nifti1Image(volume((6, 5, 4), np.float64), None)
img.set_sform(sheared, code=1)
img.set_qform(None, code=0)
cases.append(("shear_sform.nii", img))
# sform and a different qform: the sform wins.
img = nib.Nifti1Image(volume((5, 5, 5), np.int32), None)
img.set_sform(sheared, code=2)
img.set_qform(flipped, code=1)
cases.append(("sform_wins.nii.gz", img))
# Scaled integers.
img = nib.Nifti1Image(volume((6, 4, 3), np.int16), rotated)
img.header.set_slope_inter(0.25, -7.5)
cases.append(("scaled.nii", img))
# NIfTI-2, 4-D, rotated.
img = nib.Nifti2Image(volume((6, 5, 4, 3), np.float32), rotated)
cases.append(("series2.nii.gz", img))
# NIfTI-2 with a flip, qform only, uncompressed.
img = nib.Nifti2Image(volume((4, 6, 5), np.int16), None)
img.set_qform(flipped, code=1)
img.set_sform(None, code=0)
cases.append(("flip2.nii", img))
# A compressed header/image pair with a sheared sform, and a NIfTI-2 pair.
cases.append(("pair.hdr.gz", nib.Nifti1Pair(volume((5, 4, 6), np.int8), sheared)))
cases.append(("pair2.hdr", nib.Nifti2Pair(volume((3, 5, 4), np.float64), flipped)))

for name, img in cases:
    path = os.path.join(OUT, name)
    img.to_filename(path)
    loaded = nib.load(path)
    frames = tuple(range(loaded.shape[3])) if loaded.ndim == 4 else (0,)
    emit_image(path, frames)

# Neither sform nor qform: the standard's method 1. Written through the header, as nibabel's own saving sets
# an sform.
data = volume((3, 4, 5), np.uint16)
hdr = nib.Nifti1Header()
hdr.set_data_shape(data.shape)
hdr.set_data_dtype(np.uint16)
hdr.set_zooms((0.5, 0.25, 4.0))
hdr["vox_offset"] = 352
path = os.path.join(OUT, "no_transform.nii")
with open(path, "wb") as f:
    hdr.write_to(f)
    f.write(b"\0" * (352 - f.tell()))
    f.write(data.astype("<u2").tobytes(order="F"))
loaded = nib.load(path).header
assert loaded["sform_code"] == 0 and loaded["qform_code"] == 0
emit_image(path)

# Big-endian files, written through nibabel's byte-swapped header.
for name, klass, linear in [("big.nii", nib.Nifti1Image, rotated), ("big_pair.hdr", nib.Nifti1Pair, flipped)]:
    data = volume((5, 6, 4), np.int16)
    hdr = klass(data, linear).header.as_byteswapped(">")
    path = os.path.join(OUT, name)
    with open(path, "wb") as f:
        hdr.write_to(f)
        if name.endswith(".nii"):
            f.write(b"\0" * (int(hdr["vox_offset"]) - f.tell()))
            f.write(data.astype(">i2").tobytes(order="F"))
    if name.endswith(".hdr"):
        with open(path[:-4] + ".img", "wb") as f:
            f.write(data.astype(">i2").tobytes(order="F"))
    assert nib.load(path).header.endianness == ">"
    emit_image(path)

# The same volumes as MetaImage headers in ITK's LPS world: TransformMatrix lists the direction matrix column
# after column (ITK's MetaImageIO), ElementSpacing the column lengths, Offset the origin.
for name, ras in [("rotated.mha", rotated), ("flipped.mha", flipped), ("sheared.mha", sheared)]:
    lps = np.diag([-1.0, -1.0, 1.0, 1.0]) @ ras
    spacing = np.linalg.norm(lps[:3, :3], axis=0)
    direction = lps[:3, :3] / spacing
    data = volume((6, 5, 4), np.float32)
    path = os.path.join(OUT, name)
    with open(path, "wb") as f:
        f.write(("ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n"
                 "TransformMatrix = %s\nOffset = %s\nElementSpacing = %s\nDimSize = 6 5 4\n"
                 "ElementType = MET_FLOAT\nElementDataFile = LOCAL\n" %
                 (" ".join(repr(v) for v in direction.T.ravel()), " ".join(repr(v) for v in lps[:3, 3]),
                  " ".join(repr(v) for v in spacing))).encode())
        f.write(data.astype("<f4").tobytes(order="F"))
    emit(path, -1, "lps", lps, data.shape, data)
