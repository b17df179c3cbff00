"""Blender helpers that need no Blender: the sRGB curve and the log tail."""

import numpy as np

from spm_data.render.blender_scene import srgb_encode, tail


def test_srgb_encode_follows_the_standard_curve():
    linear = np.array([0.0, 0.0031308, 0.18, 0.5, 1.0, 1.7, -0.2])
    np.testing.assert_array_equal(srgb_encode(linear), [0, 10, 118, 188, 255, 255, 0])
    assert srgb_encode(np.zeros((2, 3, 3))).dtype == np.uint8


def test_tail_quotes_the_last_non_empty_lines(tmp_path):
    log = tmp_path / "blender.log"
    log.write_text("one\n\ntwo\nthree\n\nfour\n")
    assert tail(str(log)) == "three | four"  # the last three lines, the empty one dropped
    assert tail(str(tmp_path / "missing.log")) == ""


def test_srgb_encode_is_the_transfer_curve_everywhere():
    """srgb_encode sends only lit values through the curve: the same codes as the curve applied
    to the whole array, for every float32 step in [0, 1] sampled, specials and a 3-of-4 view."""
    def curve(linear):
        c = np.clip(linear, 0.0, 1.0)
        s = np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1 / 2.4) - 0.055)
        return np.round(s * 255.0).astype(np.uint8)

    bits = np.arange(0, int(np.float32(1.0).view(np.uint32)) + 1, 97, dtype=np.uint32)
    values = np.concatenate([bits.view(np.float32),
                             np.array([-0.0, -1.0, -np.inf, np.inf, 2.0, 1.0, 0.0, 1e-45], np.float32)])
    np.testing.assert_array_equal(srgb_encode(values), curve(values))
    rgba = np.zeros((len(values) // 4, 4, 4), np.float32)
    rgba[:, 1, :] = values[:len(rgba) * 4].reshape(-1, 4)
    np.testing.assert_array_equal(srgb_encode(rgba[..., :3]), curve(rgba[..., :3]))


# --------------------------------------------------------------------------- Cycles devices (--gpus)

class FakeDevice:
    def __init__(self, kind, ident):
        self.type, self.id, self.use = kind, ident, False


class FakePreferences:
    """Cycles' add-on preferences as cycles_device uses them: a Blender with CUDA and OptiX."""

    def __init__(self, devices):
        self.devices, self._kind = devices, None

    @property
    def compute_device_type(self):
        return self._kind

    @compute_device_type.setter
    def compute_device_type(self, kind):
        if kind not in ("CUDA", "OPTIX"):
            raise TypeError(f"enum {kind!r} not found")
        self._kind = kind

    def get_devices_for_type(self, kind):
        return [d for d in self.devices if d.type in (kind, "CPU")]


def fake_bpy(devices):
    from types import SimpleNamespace

    prefs = FakePreferences(devices)
    bpy = SimpleNamespace(context=SimpleNamespace(preferences=SimpleNamespace(
        addons={"cycles": SimpleNamespace(preferences=prefs)})))
    return bpy, SimpleNamespace(cycles=SimpleNamespace(device=None)), prefs


def test_gpus_pick_one_cycles_device_per_worker():
    """Not verified on a GPU here (no GPU, Blender finds none): the device list is injected."""
    import pytest

    from spm_data.errors import RenderError
    from spm_data.render.blender_scene import cycles_device

    devices = [FakeDevice("CPU", "cpu"), FakeDevice("OPTIX", "gpu-a"), FakeDevice("OPTIX", "gpu-b"),
               FakeDevice("CUDA", "gpu-a-cuda")]
    bpy, sc, prefs = fake_bpy(devices)
    assert cycles_device(bpy, sc, "auto", gpu=1) == "OPTIX" and sc.cycles.device == "GPU"
    assert [d.id for d in devices if d.use] == ["gpu-b"]            # this worker's GPU alone
    assert cycles_device(bpy, sc, "gpu") == "OPTIX"
    assert [d.id for d in devices if d.use] == ["gpu-a", "gpu-b"]   # no --gpus: every device of the backend
    with pytest.raises(RenderError, match=r"^--gpus: there is no GPU 2 for Blender; it lists 2 OPTIX devices \(0-1\)$"):
        cycles_device(bpy, sc, "auto", gpu=2)
    bpy, sc, _ = fake_bpy([FakeDevice("CPU", "cpu")])
    assert cycles_device(bpy, sc, "cpu", gpu=0) == "CPU"            # the spec says the CPU
    assert cycles_device(bpy, sc, "auto") == "CPU"
    with pytest.raises(RenderError, match=r"^--gpus 0: Blender finds no GPU here \(tried OPTIX, CUDA, HIP, ONEAPI, "
                                          r"METAL\); leave --gpus out to render on the CPU$"):
        cycles_device(bpy, sc, "auto", gpu=0)
