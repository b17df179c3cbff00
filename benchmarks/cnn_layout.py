"""What torch's channels-last layout saves the cnn method on this machine's CPU.

    python benchmarks/cnn_layout.py [--steps 40] [--rounds 3] [--threads 1] [--side 32] [--width 16]

Times, on random crops, one training step (batch 64: forward, soft cross-entropy, backward, plain
Adam; cnn_net.train_net adds weight decay and a learning-rate schedule, a few vector operations)
and the embedding of 512 crops, for the network as spm_model/methods/cnn_net.py builds it (channels
last) and for the same network in torch's default layout (NCHW), alternating the two
``--rounds`` times so that a busy machine slows both alike. Prints the median milliseconds of each
and their ratio. The layout changes no parameter name, shape or value, only the order in memory
and the rounding of the sums (results are deterministic in either).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from spm_model.methods import cnn_net  # noqa: E402


def timed_network(torch, layout: str, side: int, width: int, steps: int) -> tuple[float, float]:
    """(ms per training step, ms per embedding of 512 crops) of a fresh network in ``layout``
    ("channels_last" or "nchw")."""
    torch.manual_seed(0)
    net = cnn_net.make_net(torch, side, width, 64, 256)
    fmt = torch.channels_last if layout == "channels_last" else torch.contiguous_format
    net = net.to(memory_format=fmt)

    def forward(x):   # cnn_net.embeddings, with the layout asked for
        z = net["embed"](net["features"](x.contiguous(memory_format=fmt)))
        return torch.nn.functional.normalize(z, dim=1)

    x, target = torch.rand(64, 2, side, side), torch.softmax(torch.randn(64, 256), dim=1)
    optimiser = torch.optim.Adam(net.parameters(), lr=1e-3)

    def step():
        loss = -(target * net["head"](forward(x) * 16.0).log_softmax(dim=1)).sum(dim=1).mean()
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()

    for _ in range(3):   # warm-up: the first calls allocate and pick kernels
        step()
    start = time.perf_counter()
    for _ in range(steps):
        step()
    train_ms = (time.perf_counter() - start) / steps * 1000
    net.eval()
    queries = torch.rand(512, 2, side, side)
    with torch.no_grad():
        forward(queries)
        start = time.perf_counter()
        for _ in range(3):
            forward(queries)
    return train_ms, (time.perf_counter() - start) / 3 * 1000


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads (benchmark jobs use 1)")
    parser.add_argument("--side", type=int, default=32)
    parser.add_argument("--width", type=int, default=16)
    args = parser.parse_args(argv)
    if args.steps < 1 or args.rounds < 1 or args.threads < 1 or args.side % 16 or args.side < 16 or args.width < 1:
        print("error: --steps, --rounds, --threads and --width must be >= 1 and --side a multiple of 16",
              file=sys.stderr)
        return 1
    torch = cnn_net.torch_module()
    threads = torch.get_num_threads()
    torch.set_num_threads(args.threads)
    times = {"nchw": [], "channels_last": []}
    try:
        for _ in range(args.rounds):
            for layout in times:
                times[layout].append(timed_network(torch, layout, args.side, args.width, args.steps))
    finally:
        torch.set_num_threads(threads)   # main() is called by tests in their own process
    median = {k: [statistics.median(t[i] for t in v) for i in range(2)] for k, v in times.items()}
    print(f"torch {torch.__version__}, {args.threads} thread(s), {args.side} px crops, width {args.width}, "
          f"{args.rounds} rounds of {args.steps} steps (medians)")
    for i, what in enumerate(("training step, batch 64", "embedding 512 crops")):
        a, b = median["nchw"][i], median["channels_last"][i]
        print(f"{what}: NCHW {a:.1f} ms, channels last {b:.1f} ms, {a / b:.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
