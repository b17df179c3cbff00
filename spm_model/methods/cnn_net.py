"""The learned method's network and its training loop: the only module that imports torch.

torch is the optional extra ``learn`` (``pip install 'spm[learn]'``; make install includes it).
It is imported lazily, on the first fit or predict of a CNNPose, so every other method, and
spm itself, works without it; without it that call fails with one ModelError naming the extra.

The network (``make_net``): four 3x3 convolution blocks (convolution, batch norm, ReLU, 2x2 max
pool; ``width``, 2, 4, 4 x ``width`` channels) on the 2-channel crop (masked grey, mask), a
linear layer to the ``embed``-dimensional embedding, and a linear head over the view bins.
Its parameters are named as torch names them (``features.0.weight``, ``embed.weight``,
``head.bias``, ``features.1.running_mean``, ...): those names and arrays are the model file's
``net/...`` arrays and the safetensors file's tensors (spm_model/base/safetensors_file.py).
"""

from __future__ import annotations

import contextlib
import time

import numpy as np

from spm_model.errors import ModelError

INSTALL_HINT = "pip install 'spm[learn]' (make install includes it)"


def torch_module():
    """The torch module; ModelError (one line, naming the extra) when it is not installed."""
    try:
        import torch
    except ImportError:
        raise ModelError(f"the cnn method needs PyTorch, which is not installed here; {INSTALL_HINT}") from None
    return torch


DEVICES = "auto, cpu, cuda or cuda:N"


def resolve_device(torch, device: str) -> str:
    """'auto' -> 'cuda' when torch sees a GPU, else 'cpu'; 'cpu', 'cuda', 'cuda:N' as given when torch
    can use it; ModelError (one line: what was asked, what is here, the fix) otherwise."""
    device = str(device).strip()
    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if device == "cpu":
        return device
    kind, _, index = device.partition(":")
    if kind != "cuda" or (index and not index.isdigit()):
        raise ModelError(f"device {device!r} is not one the cnn method takes; give {DEVICES}")
    gpus = torch.cuda.device_count() if torch.cuda.is_available() else 0
    if gpus == 0:
        raise ModelError(f"device {device!r}: torch sees no GPU here (a CPU-only build or no CUDA device); "
                         "give --device cpu, or auto (which falls back to cpu)")
    if index and int(index) >= gpus:
        raise ModelError(f"device {device!r}: torch sees {gpus} GPU{'s' if gpus > 1 else ''} (cuda:0"
                         f"{f' to cuda:{gpus - 1}' if gpus > 1 else ''}); give one of them, cuda, cpu or auto")
    return device


def device_line(torch, device: str) -> str:
    """What ``device`` resolves to, said in one line for the CLI: "cnn device: cuda:0 (NVIDIA ...)",
    "cnn device: cpu (auto: torch sees no GPU here)"."""
    resolved = resolve_device(torch, device)
    if resolved == "cpu":
        return "cnn device: cpu" + (" (auto: torch sees no GPU here, so the CPU)" if device == "auto" else "")
    name = torch.cuda.get_device_name(torch.device(resolved))
    return f"cnn device: {resolved} ({name}{'; auto' if device == 'auto' else ''})"


def make_net(torch, side: int, width: int, embed: int, bins: int):
    """A fresh network for side x side crops (module docstring): ModuleDict of features, embed, head."""
    nn = torch.nn
    layers, channels = [], 2
    for out in (width, 2 * width, 4 * width, 4 * width):
        layers += [nn.Conv2d(channels, out, 3, padding=1, bias=False), nn.BatchNorm2d(out), nn.ReLU(),
                   nn.MaxPool2d(2)]
        channels = out
    net = nn.ModuleDict({"features": nn.Sequential(*layers, nn.Flatten()),
                         "embed": nn.Linear(channels * (side // 16) ** 2, embed), "head": nn.Linear(embed, bins)})
    return net.to(memory_format=torch.channels_last)   # see embeddings()


def embeddings(torch, net, x):
    """Unit-length embeddings of a batch (n, 2, s, s) float tensor. The network and its input are in
    torch's channels-last layout: on a CPU a training step then runs about 1.6 times as fast as in
    the default layout, an embedding 1.5 to 2 times (benchmarks/cnn_layout.py; docs/method.md
    "Network"). The parameters' names and shapes (state_arrays, the model files) are those of either
    layout, and a network saved in one loads in the other; the sums round differently, so the two
    layouts' embeddings agree to float rounding, not bit for bit."""
    z = net["embed"](net["features"](x.contiguous(memory_format=torch.channels_last)))
    return torch.nn.functional.normalize(z, dim=1)


@contextlib.contextmanager
def torch_settings(torch, seed: int, threads: int):
    """Seeded, deterministic algorithms and ``threads`` intra-op threads; the caller's settings back after."""
    before = (torch.get_num_threads(), torch.are_deterministic_algorithms_enabled())
    torch.set_num_threads(max(1, int(threads)))
    torch.use_deterministic_algorithms(True, warn_only=True)   # warn_only: CUDA ops without a deterministic kernel
    torch.manual_seed(seed)
    try:
        yield
    finally:
        torch.set_num_threads(before[0])
        torch.use_deterministic_algorithms(before[1])


def train_net(torch, net, batches, targets: np.ndarray, *, steps: int, lr: float, device: str) -> dict:
    """Train ``net`` for ``steps`` steps of Adam (one-cycle learning rate peaking at ``lr``) on the
    soft cross-entropy between its bin scores and ``targets`` (n, bins) rows; ``batches(step)``
    gives (indices (b,), inputs (b, 2, s, s) float32). Returns {seconds, steps, device}."""
    start = time.perf_counter()
    net.to(device).train()
    optimiser = torch.optim.Adam(net.parameters(), lr=lr, weight_decay=1e-4)
    schedule = torch.optim.lr_scheduler.OneCycleLR(optimiser, max_lr=lr, total_steps=max(1, steps))
    target = torch.from_numpy(targets.astype(np.float32)).to(device)
    for step in range(steps):
        index, x = batches(step)
        scores = net["head"](embeddings(torch, net, torch.from_numpy(x).to(device)) * 16.0)
        loss = -(target[torch.from_numpy(index).to(device)] * scores.log_softmax(dim=1)).sum(dim=1).mean()
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        schedule.step()
    net.eval()
    return {"seconds": time.perf_counter() - start, "steps": int(steps), "device": device}


def embed_all(torch, net, x: np.ndarray, device: str, block: int = 512) -> np.ndarray:
    """(n, embed) float32 unit embeddings of inputs (n, 2, s, s), in blocks, without gradients."""
    placed(torch, net, device)
    out = []
    with torch.no_grad():
        for s in range(0, len(x), block):
            out.append(embeddings(torch, net, torch.from_numpy(x[s: s + block]).to(device)).cpu().numpy())
    return np.concatenate(out) if out else np.zeros((0, net["head"].in_features), np.float32)


def placed(torch, net, device: str):
    """``net`` on ``device`` in eval mode, moved or switched only when it is not already: moving
    walks every module, about 10 ms a call on a CPU, more than one crop's forward pass costs."""
    want, have = torch.device(device), next(net.parameters()).device
    if have.type != want.type or (want.index is not None and have.index != want.index):
        net.to(want)
    if net.training:
        net.eval()
    return net


def state_arrays(net) -> dict:
    """{name: float32 or int64 array} of every parameter and buffer, in torch's order."""
    return {k: v.detach().cpu().numpy().copy() for k, v in net.state_dict().items()}


def net_from_arrays(torch, arrays: dict, side: int, width: int, embed: int, bins: int):
    """The network ``state_arrays`` describes (ValueError when they do not fit it)."""
    net = make_net(torch, side, width, embed, bins)
    try:
        net.load_state_dict({k: torch.from_numpy(np.ascontiguousarray(v)) for k, v in arrays.items()})
    except RuntimeError as exc:
        raise ValueError(f"the network's arrays do not fit it ({str(exc).splitlines()[0]})") from None
    return net.eval()
