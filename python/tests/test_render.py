"""cip.render gives the image the raycast command writes: every EXR channel equal, read back with OpenImageIO."""
import subprocess

import numpy as np
import pytest

import cip

oiio = pytest.importorskip("OpenImageIO")


def read_exr(path):
    image = oiio.ImageInput.open(str(path))
    spec = image.spec()
    names = list(spec.channelnames)
    channels = {}
    for c, name in enumerate(names):
        kind = oiio.UINT32 if name == "id" else oiio.FLOAT
        channels[name] = image.read_image(0, 0, c, c + 1, kind)[:, :, 0]
    image.close()
    return channels


@pytest.mark.parametrize("args,kwargs", [
    ([], {}),
    (["--eye", "60,-50,40", "--look", "20,20,20", "--up", "0,0,1", "--fov", "30", "--shading", "curvature"],
     dict(eye=(60, -50, 40), look=(20, 20, 20), up=(0, 0, 1), fov=30, shading="curvature")),
    (["--shading", "normal", "--spp", "4", "--ortho"], dict(shading="normal", spp=4, ortho=True)),
])
def test_same_image_as_the_command(tmp_path, raycast_exe, blobs_path, args, kwargs):
    model = cip.extract(blobs_path, 128)
    model.save(str(tmp_path / "m.cip"))
    subprocess.run([raycast_exe, str(tmp_path / "m.cip"), "-o", str(tmp_path / "m.exr"), "--size", "96x64", "-q"]
                   + args, check=True)
    expected = read_exr(tmp_path / "m.exr")
    seen = []
    image = cip.render(model, size=(96, 64), progress=seen.append, **kwargs)
    assert sorted(image) == sorted(expected)
    for name, channel in image.items():
        assert channel.shape == (64, 96)
        assert channel.dtype == (np.uint32 if name == "id" else np.float32)
        np.testing.assert_array_equal(channel, expected[name], err_msg=name)
    assert 0 < (image["A"] > 0).sum() < 96 * 64  # the blobs are in view, not filling it
    assert seen[-1] == 1.0


def test_render_errors(blobs_path):
    model = cip.extract(blobs_path, 128)
    with pytest.raises(cip.Error, match="shading"):
        cip.render(model, shading="toon")
    with pytest.raises(cip.Error, match="size"):
        cip.render(model, size=(0, 10))
    with pytest.raises(cip.Error, match="eye"):
        cip.render(model, eye=(1, 2))
    with pytest.raises(TypeError):
        cip.render("m.cip")
