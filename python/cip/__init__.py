"""cip: corner-patch isosurfaces from voxel volumes.

    import numpy as np, cip
    verts, faces, normals, values = cip.marching_cubes(volume, 0.5)      # scikit-image's conventions
    model = cip.extract(volume, 0.5, spacing=(1, 1, 2))                    # smooth corner-patch model
    model.save("v.cip"); cip.write_mesh("v.glb", *model.patch_mesh(subdiv=4))
    image = cip.render(model, size=(640, 480))                             # dict of H x W arrays

Errors from the library are cip.Error (a ValueError) with the library's message. Long calls release the GIL,
report progress through `progress(fraction)` and stop cleanly on Ctrl-C (KeyboardInterrupt).
"""
import numbers
import os
import warnings

import numpy as np

from ._cip import Error, Model, load, write_mesh  # noqa: F401
from . import _cip

__all__ = ["Error", "Model", "extract", "extract_labels", "load", "marching_cubes", "render", "write_mesh"]


def _volume(volume):
    """The array as the compiled part takes it: numeric, native byte order; a copy only for other dtypes."""
    array = np.asarray(volume)
    if array.dtype.kind not in "biuf":
        raise TypeError("volume must be a numeric array, got dtype %s" % array.dtype)
    if array.dtype.kind == "f" and array.dtype.itemsize not in (4, 8):
        array = array.astype(np.float64)  # float16, longdouble
    elif not array.dtype.isnative:
        array = array.astype(array.dtype.newbyteorder("="))
    return array


def marching_cubes(volume, level=None, *, spacing=(1.0, 1.0, 1.0), gradient_direction="descent", step_size=1,
                   allow_degenerate=True, method="lewiner", mask=None, threads=0, progress=None):
    """skimage.measure.marching_cubes on cip's own implementation: the same mesh, in the same order.

    Lewiner et al.'s case tables with their face and interior tests and interior vertices (method='lewiner',
    the default) or Lorensen's classic table (method='lorensen'), computed as scikit-image computes them:
    samples converted to float32 (read in place from any numeric dtype, C or Fortran order or a strided view,
    no copy), vertices at the linear edge crossings in the array's axis order times `spacing`, normals the
    index-space gradients pointing to lower values, values the largest range of samples among the cells around
    each vertex, faces wound for `gradient_direction` ('descent': the object has the higher values).
    Returns (verts (V, 3) float32, or float64 once scaled by a spacing other than 1, faces (F, 3) int32,
    normals (V, 3) float32, values (V,) float32). `level` defaults to the middle of the data's range;
    `step_size` cells of step_size^3 samples; `mask` a boolean array of the volume's shape (a cell is visited
    where the mask is true at its far corner, as in scikit-image); allow_degenerate=False merges the vertices
    of zero-area triangles and drops those triangles. NaN or infinite samples raise cip.Error. Without a mask,
    slabs of cells are walked on `threads` threads (0 = all) and joined into exactly the serial walk's result;
    the work runs without the GIL, reports progress through `progress(fraction)` and stops on Ctrl-C.
    """
    if method not in ("lewiner", "lorensen"):
        raise ValueError("method should be one of 'lewiner' or 'lorensen'.")
    if gradient_direction not in ("descent", "ascent"):
        raise ValueError("Incorrect input %s in `gradient_direction`, see docstring." % (gradient_direction,))
    if len(spacing) != 3:
        raise ValueError("`spacing` must consist of three floats.")
    step_size = int(step_size)
    if step_size < 1:
        raise ValueError("step_size must be at least one.")
    volume = np.asarray(volume)
    if volume.dtype.kind == "f" and volume.dtype.itemsize > 8:
        volume = volume.astype(np.float32)  # long double: one rounding to float32, as scikit-image's
    volume = _volume(volume)
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != volume.shape:
            raise ValueError("volume and mask must have the same shape.")
        if mask.dtype != np.bool_:
            mask = mask.astype(np.bool_)
    verts, faces, normals, values = _cip._marching_cubes(volume, level, step_size, method,
                                                         gradient_direction == "descent", mask, int(threads),
                                                         progress)
    if not len(verts):
        raise RuntimeError("No surface found at the given iso value.")
    if not np.array_equal(spacing, (1, 1, 1)):
        verts = verts * np.r_[spacing]  # float64, as scikit-image
    if not allow_degenerate:
        verts, faces, normals, values = _cip._remove_degenerate_faces(verts.astype(np.float32), faces, normals,
                                                                      values)
        faces = faces.astype(np.int_)  # scikit-image renumbers them with a cumsum: the default integer
    return verts, faces, normals, values


def extract(volume_or_path, level=None, *, spacing=None, origin=None, method="fitted", normals="gradient",
            reconstruction="auto", threads=0, progress=None, skip_nonfinite=False, grid="", frame=None,
            label=None):
    """Builds a corner-patch model (cip.Model) from a 3-D array or a volume file, as the `extract` command does.

    volume_or_path: a numeric 3-D array (axis order = x, y, z of the model; spacing and origin place it in the
    world, default 1 and 0) or a file the command reads (.nrrd/.nhdr, .nii/.nii.gz/.hdr/.img, .mha/.mhd, .vdb;
    `grid` names the VDB grid, `frame` the volume of a 4-D NIfTI, NRRD or MetaImage series, from 0). level: the isovalue (default: the middle of an array's range, 0 for level sets; other files need
    one). method 'fitted' or 'paper', normals 'gradient', 'edge' or 'exact', reconstruction 'auto', 'monotone',
    'central8' or 'mask' as the command's flags (auto takes mask on two-valued data such as segmentation masks). threads: 0 = all. progress: called with the fraction done in [0, 1].
    label: an integer N makes the volume a label map and the model the surface of the voxels labelled N, as
    `extract --label N` (no level then; extract_labels gives every label's).
    Runs without the GIL; Ctrl-C stops it (KeyboardInterrupt), as does an exception raised by `progress`.
    NaN or infinite samples at crossed cells raise cip.Error unless skip_nonfinite=True.
    """
    if label is not None and (isinstance(label, (bool, str)) or not isinstance(label, numbers.Integral)):
        raise TypeError("label must be an integer, got %r" % (label,))
    models, lo, hi = _extract_models(volume_or_path, level, spacing, origin, method, normals, reconstruction,
                                     threads, progress, skip_nonfinite, grid, frame,
                                     None if label is None else int(label))
    model = models[0][1]
    if label is None and not (lo < model.isovalue < hi):
        warnings.warn("isovalue %g is outside the data range [%g, %g]; the surface is empty" % (model.isovalue, lo, hi))
    return model


def extract_labels(volume_or_path, *, spacing=None, origin=None, normals="gradient", threads=0, progress=None,
                   skip_nonfinite=False, grid="", frame=None):
    """One model per non-zero label of a label map (an integer array or file), as `extract --labels`: a dict
    {label: cip.Model} in increasing label order. Each model is the surface of the voxels with that label;
    the surfaces of touching labels meet (docs/method.md, "Masks and label maps"). The volume is read once;
    progress runs over all the labels. Arguments as extract's.
    """
    models, _, _ = _extract_models(volume_or_path, None, spacing, origin, "fitted", normals, "auto", threads,
                                   progress, skip_nonfinite, grid, frame, "all")
    return {int(l): m for l, m in models}


def _extract_models(volume_or_path, level, spacing, origin, method, normals, reconstruction, threads, progress,
                    skip_nonfinite, grid, frame, label):
    if isinstance(volume_or_path, (str, os.PathLike)):
        volume_or_path = os.fspath(volume_or_path)
        if not os.path.exists(volume_or_path):
            raise FileNotFoundError(2, "No such file", volume_or_path)
    else:
        volume_or_path = _volume(volume_or_path)
    return _cip._extract(volume_or_path, level, spacing, origin, method, normals, reconstruction, threads,
                         progress, skip_nonfinite, grid, -1 if frame is None else int(frame), label)


def render(model, eye=None, look=None, up=None, fov=35.0, size=(800, 600), *, shading="phong", spp=1,
           shadows=False, ortho=False, curvature_range=None, threads=0, progress=None, space=None):
    """Renders a model as the `raycast` command does; returns its EXR channels as a dict of H x W arrays.

    Keys: 'R', 'G', 'B', 'A' (linear, premultiplied), 'Z' (distance along the pixel-centre ray, inf where it
    misses), 'N.x', 'N.y', 'N.z' (world normal), all float32, and 'id' (uint32 cell index, 0xFFFFFFFF where
    it misses). Unset eye, look and up frame the model as the command does; shading is 'phong', 'cells',
    'normal', 'depth', 'curvature' or 'isophotes'. The same arguments give the same image as the command.
    Camera and normals are in the model's world (`model.affine`); space='ras', 'las' or 'lps' converts it,
    as `raycast --space` does.
    """
    if not isinstance(model, Model):
        raise TypeError("render needs a cip.Model, got %s" % type(model).__name__)
    width, height = size
    return _cip._render(model, eye, look, up, float(fov), (int(width), int(height)), shading, int(spp),
                        bool(shadows), bool(ortho), curvature_range, int(threads), progress, space)
