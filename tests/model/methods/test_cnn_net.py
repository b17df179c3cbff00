from types import SimpleNamespace

import numpy as np
import pytest

from spm_model.errors import ModelError
from spm_model.methods import cnn_net

torch = cnn_net.torch_module()   # the suite runs with the extra learn installed (make install)


def test_the_network_embeds_to_unit_length_and_its_arrays_rebuild_it():
    with cnn_net.torch_settings(torch, seed=0, threads=1):
        net = cnn_net.make_net(torch, 32, 4, 8, 5).eval()
        x = np.random.default_rng(0).random((3, 2, 32, 32)).astype(np.float32)
        z = cnn_net.embed_all(torch, net, x, "cpu")
        assert z.shape == (3, 8) and np.allclose(np.linalg.norm(z, axis=1), 1, atol=1e-6)
        arrays = cnn_net.state_arrays(net)
        assert arrays["head.weight"].shape == (5, 8) and arrays["embed.weight"].shape == (8, 16 * 2 * 2)
        again = cnn_net.net_from_arrays(torch, arrays, 32, 4, 8, 5)
        assert np.array_equal(cnn_net.embed_all(torch, again, x, "cpu"), z)
        with pytest.raises(ValueError, match="the network's arrays do not fit it"):
            cnn_net.net_from_arrays(torch, arrays, 32, 4, 8, 6)


def test_a_network_saved_in_torchs_default_layout_loads_and_embeds_alike():
    """Model files written before the network moved to channels-last (its arrays then came from an
    NCHW network) load into today's and embed to float rounding alike; the layout is in memory only."""
    with cnn_net.torch_settings(torch, seed=0, threads=1):
        net = cnn_net.make_net(torch, 32, 4, 8, 5).eval()
        assert net["features"][0].weight.is_contiguous(memory_format=torch.channels_last)
        old = net.to(memory_format=torch.contiguous_format)
        assert old["features"][0].weight.is_contiguous()
        assert not old["features"][0].weight.is_contiguous(memory_format=torch.channels_last)
        x = torch.from_numpy(np.random.default_rng(1).random((6, 2, 32, 32)).astype(np.float32))
        with torch.no_grad():
            before = torch.nn.functional.normalize(old["embed"](old["features"](x)), dim=1).numpy()
        arrays = cnn_net.state_arrays(old)
        again = cnn_net.net_from_arrays(torch, arrays, 32, 4, 8, 5)
        assert again["features"][0].weight.is_contiguous(memory_format=torch.channels_last)
        assert np.allclose(cnn_net.embed_all(torch, again, x.numpy(), "cpu"), before, atol=1e-5)
        saved = cnn_net.state_arrays(again)   # from a channels-last net: C-ordered, the same values
        assert all(v.flags["C_CONTIGUOUS"] and np.array_equal(v, arrays[k]) for k, v in saved.items())


def test_training_lowers_the_loss_on_separable_targets_and_settings_are_restored():
    threads, deterministic = torch.get_num_threads(), torch.are_deterministic_algorithms_enabled()
    x = np.zeros((8, 2, 16, 16), np.float32)
    for i in range(8):
        x[i, :, i: i + 6, 2: 14] = 1.0                                # a bar at 8 heights: 2 bins
    targets = np.eye(2, dtype=np.float32)[np.arange(8) // 4]
    with cnn_net.torch_settings(torch, seed=0, threads=1):
        net = cnn_net.make_net(torch, 16, 4, 8, 2)
        cost = cnn_net.train_net(torch, net, lambda step: (np.arange(8), x), targets, steps=60, lr=0.01,
                                 device="cpu")
        scores = net["head"](cnn_net.embeddings(torch, net, torch.from_numpy(x)) * 16.0).detach().numpy()
    assert cost["steps"] == 60 and cost["device"] == "cpu" and cost["seconds"] > 0
    assert (scores.argmax(axis=1) == np.arange(8) // 4).all()
    assert (torch.get_num_threads(), torch.are_deterministic_algorithms_enabled()) == (threads, deterministic)


def fake_torch(gpus: int):
    """torch's device queries as a machine with ``gpus`` GPUs answers them."""
    cuda = SimpleNamespace(is_available=lambda: gpus > 0, device_count=lambda: gpus,
                           get_device_name=lambda device: f"GPU{device.index or 0}")
    return SimpleNamespace(cuda=cuda, device=torch.device)


def test_devices_auto_resolves_and_an_unknown_one_is_one_error():
    assert cnn_net.resolve_device(torch, "auto") == ("cuda" if torch.cuda.is_available() else "cpu")
    assert cnn_net.resolve_device(torch, "cpu") == "cpu"
    for bad in ("gpu0", "mps", "cuda:x", "cuda:-1", ""):
        with pytest.raises(ModelError, match=f"^device {bad!r} is not one the cnn method takes; give auto, cpu, "
                                             "cuda or cuda:N$"):
            cnn_net.resolve_device(torch, bad)


def test_cuda_without_a_gpu_is_one_error_and_auto_falls_back_to_the_cpu():
    cpu_only = fake_torch(0)
    assert cnn_net.resolve_device(cpu_only, "auto") == "cpu"
    assert cnn_net.device_line(cpu_only, "auto") == "cnn device: cpu (auto: torch sees no GPU here, so the CPU)"
    assert cnn_net.device_line(cpu_only, "cpu") == "cnn device: cpu"
    for asked in ("cuda", "cuda:0"):
        with pytest.raises(ModelError, match=rf"^device '{asked}': torch sees no GPU here \(a CPU-only build or no "
                                             r"CUDA device\); give --device cpu, or auto \(which falls back to cpu\)$"):
            cnn_net.resolve_device(cpu_only, asked)


def test_a_gpu_torch_sees_is_taken_and_one_past_the_count_refused():
    two = fake_torch(2)
    assert [cnn_net.resolve_device(two, d) for d in ("auto", "cuda", "cuda:1", "cpu")] == ["cuda", "cuda", "cuda:1",
                                                                                            "cpu"]
    assert cnn_net.device_line(two, "cuda:1") == "cnn device: cuda:1 (GPU1)"
    assert cnn_net.device_line(two, "auto") == "cnn device: cuda (GPU0; auto)"
    with pytest.raises(ModelError, match=r"^device 'cuda:2': torch sees 2 GPUs \(cuda:0 to cuda:1\); give one of "
                                         "them, cuda, cpu or auto$"):
        cnn_net.resolve_device(two, "cuda:2")
    with pytest.raises(ModelError, match=r"^device 'cuda:1': torch sees 1 GPU \(cuda:0\)"):
        cnn_net.resolve_device(fake_torch(1), "cuda:1")
