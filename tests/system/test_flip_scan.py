"""A shard is trusted only whole: a single-bit flip of any metadata byte (anything
that is not a chunk's stored data) is refused by every reader, one error naming the
shard, never wrong values or a traceback (docs/reliability.md, "Every byte").

The full scan checks every metadata byte against the header check every open runs
first (seal.check, in memory, a few seconds); a spread of flips then goes through
every library reader and every command that reads shards. benchmarks/flip_scan.py
runs the full scan through the readers themselves (minutes)."""

import hashlib
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from cli import data_cli, model_cli
from spm_data.errors import ShardError
from spm_data.io.loaders import ShardDataset
from spm_data.io.shards import (ShardReader, read_attrs, read_shard, shard_layout, verify_shard, write_manifest,
                                write_shard)
from spm_data.io.shards.seal import USERBLOCK, SealError, check
from tests.helpers import make_arrays, payload_positions

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def shard(tmp_path_factory):
    """4 frames of 8x10 pixels with every field, in a folder with its manifest."""
    folder = tmp_path_factory.mktemp("flip") / "shards"
    folder.mkdir()
    write_shard(folder / "s-00000.h5", make_arrays(n=4, h=8, w=10), {"renderer": "x", "seed": 0, "spec": "class"})
    write_manifest(folder)
    return folder / "s-00000.h5"


def test_every_metadata_bit_flip_fails_the_check_every_open_runs(shard):
    data = shard.read_bytes()
    inside = payload_positions(shard)
    metadata = [p for p in range(len(data)) if p not in inside]
    assert len(metadata) > 0.9 * len(data) and len(inside) > 1000  # what is scanned: most of a small shard
    step = 4096  # SHA-256 states of the content's prefixes, so a flip rehashes only what follows it
    states, h = [], hashlib.sha256()
    for start in range(USERBLOCK, len(data), step):
        states.append(h.copy())
        h.update(data[start:start + step])
    assert check(data[:USERBLOCK], h.hexdigest)  # the clean shard passes
    passed = []
    for p in metadata:
        if p < USERBLOCK:
            header = bytearray(data[:USERBLOCK])
            header[p] ^= 1 << (p % 8)
            block, content = bytes(header), h.hexdigest
        else:
            k = (p - USERBLOCK) // step
            start = USERBLOCK + k * step
            flipped = bytearray(data[start:])
            flipped[p - start] ^= 1 << (p % 8)
            block, state = data[:USERBLOCK], states[k].copy()
            state.update(flipped)
            content = state.hexdigest
        try:
            check(block, content)
        except SealError:
            continue
        passed.append(p)
    assert passed == []


def test_only_the_reader_opens_a_shard():
    """Every reader reaches the check: nothing but the shard reader and writer opens an HDF5 file."""
    opened = [str(p.relative_to(ROOT)) for folder in ("spm_data", "spm_model", "cli")
              for p in (ROOT / folder).rglob("*.py") if re.search(r"h5py\.File\(|\bh5f\.open\(", p.read_text())]
    assert sorted(opened) == ["spm_data/io/shards/reader.py", "spm_data/io/shards/writer.py"]


def spread(path, count=24) -> list[int]:
    """Flip positions across the file: the header, HDF5's superblock, object headers and
    indexes, the attributes, and a few chunk bytes."""
    size = path.stat().st_size
    inside = sorted(payload_positions(path))
    metadata = sorted(set(range(size)) - set(inside))
    picks = [3, 40, 300, USERBLOCK, USERBLOCK + 9, USERBLOCK + 40]
    picks += [metadata[i] for i in np.linspace(0, len(metadata) - 1, count).astype(int)]
    picks += [inside[len(inside) // 3], inside[-1]]
    return sorted(set(picks))


def flipped_copy(shard, at, tmp_path) -> Path:
    folder = shutil.copytree(shard.parent, tmp_path / f"flip-{at}")
    path = folder / shard.name
    data = bytearray(path.read_bytes())
    data[at] ^= 1 << (at % 8)
    path.write_bytes(bytes(data))
    return path


LIBRARY = {
    "read_shard": lambda p: read_shard(p),
    "ShardReader": lambda p: ShardReader(p).read(["rgb", "pose"]),
    "read_attrs": read_attrs,
    "shard_layout": shard_layout,
    "verify_shard": verify_shard,
    "ShardDataset": lambda p: ShardDataset(p.parent)[0],
}


def test_a_spread_of_flips_is_refused_by_every_library_reader(shard, tmp_path):
    for at in spread(shard):
        path = flipped_copy(shard, at, tmp_path)
        for name, reader in LIBRARY.items():
            with pytest.raises(ShardError) as info:
                reader(path)
            assert str(path) in str(info.value), (name, at, info.value)
        shutil.rmtree(path.parent)


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    """A reference model file (spm evaluate loads it before reading shards)."""
    from spm_model.methods.template import TemplatePose
    from spm_data.core.poses import intrinsics_from_fov

    rng = np.random.default_rng(0)
    images = [(rng.random((32, 32, 3)) * 255).astype(np.uint8) for _ in range(4)]
    K = intrinsics_from_fov(35, 32, 32)
    y = np.column_stack([rng.uniform(-170, 170, (4, 3)), np.zeros((4, 2)), np.full(4, 0.6)])
    frames = [{"rgb": im, "mask": np.ones((32, 32), bool), "K": K} for im in images]
    return TemplatePose().fit(frames, y).save(tmp_path_factory.mktemp("model") / "reference-model.npz")


def commands(path, out, model):
    folder = path.parent
    return {
        "validate": (data_cli, ["validate", folder]),
        "info": (data_cli, ["info", path]),
        "show": (data_cli, ["show", path, "--out", out / "sheet.png"]),
        "hist": (data_cli, ["hist", folder, "--out", out / "hist.png"]),
        "occlude": (data_cli, ["occlude", "--in", folder, "--out", out / "occ"]),
        "merge": (data_cli, ["merge", folder, "--out", out / "merged"]),
        "export": (data_cli, ["export", "bop", folder, "--out", out / "bop"]),
        "train": (model_cli, ["train", "--shards", folder, "--report", out / "report", "--runs", "1"]),
        "evaluate": (model_cli, ["evaluate", "--model", model, "--shards", folder]),
    }


def test_a_spread_of_flips_is_refused_by_every_command(shard, model, tmp_path):
    positions = spread(shard, count=6)
    for at in positions:
        path = flipped_copy(shard, at, tmp_path)
        out = tmp_path / f"out-{at}"
        out.mkdir()
        for name, (cli, args) in commands(path, out, model).items():
            r = CliRunner().invoke(cli, [str(a) for a in args])
            assert r.exit_code == 1, (name, at, r.output)
            assert "Traceback" not in r.output and (r.exception is None or isinstance(r.exception, SystemExit))
            assert str(path) in r.output or (name == "validate" and path.name in r.output), (name, at, r.output)
            if name != "validate":
                errors = [line for line in r.output.splitlines() if line.startswith("error: ")]
                assert len(errors) == 1, (name, at, r.output)
        assert list(out.iterdir()) == [], at  # nothing written
        assert not (path.parent / ".spm-features").exists()  # no cache folder left
        shutil.rmtree(path.parent)
