"""spm_model.bench.feature_cache: features of a shard tree, cached next to the shards and refreshed when a
shard changes; one-line errors; half-written cache files of dead processes removed."""

import os
import shutil
import warnings

import numpy as np
import pytest

from spm_data.errors import ShardError
from spm_data.io.shards import read_shard, write_manifest, write_shard
from spm_model.bench import feature_cache
from spm_model.bench.feature_cache import cache_path, find_shards, load_features
from spm_model.spm.features import FeatureConfig


def test_features_are_cached_next_to_the_shards_and_refreshed(model_shards, tmp_path, monkeypatch):
    folder = tmp_path / "shards"
    shutil.copytree(model_shards, folder / "nested")      # found recursively
    config = FeatureConfig(ellipse="direct")
    table = load_features(folder, config)
    assert len(table) == 144 and sorted(set(table.class_name)) == ["box", "car", "cup"]
    assert table.train_vector.shape == (144, 16) and table.raw.shape == (144, 1024)
    ok = np.isfinite(table.train_vector).all(axis=1)
    assert ok.mean() > 0.5 and np.isfinite(table.query_vector).all(axis=1).mean() > 0.9
    # A failed frame is NaN, never zeros.
    assert not (table.train_vector == 0).all(axis=1).any()
    shard = find_shards(folder)[0]
    assert cache_path(shard, config).is_file() and cache_path(shard, config).parent.name == ".spm-features"

    calls = []
    monkeypatch.setattr(feature_cache, "frames_features", lambda *a, **k: calls.append(1))
    again = load_features(folder, config)                 # second run: nothing recomputed
    assert calls == [] and np.array_equal(again.query_vector, table.query_vector, equal_nan=True)
    monkeypatch.undo()

    # Rewriting a shard invalidates its cache entry only.
    arrays = read_shard(shard)
    arrays["pose"][:, 2] += 1.0
    write_shard(shard, arrays, {"renderer": "pyrender", "seed": 1})
    write_manifest(shard.parent)   # a rewritten shard, listed again
    refreshed = load_features(folder, config)
    changed = refreshed.shard == str(shard)
    assert np.allclose(refreshed.pose[changed, 2], table.pose[changed, 2] + 1.0)


def test_no_shards_and_missing_class_are_one_line_errors(tmp_path, model_shards):
    (tmp_path / "empty").mkdir()
    with pytest.raises(ShardError, match="no shards"):
        load_features(tmp_path / "empty")
    shard = find_shards(model_shards)[0]
    arrays = read_shard(shard)
    arrays["class_name"] = np.array([""] * len(arrays["pose"]), dtype=object)
    (tmp_path / "nameless").mkdir()
    write_shard(tmp_path / "nameless" / "x.h5", arrays, {"renderer": "pyrender", "seed": 1})
    write_manifest(tmp_path / "nameless")
    with pytest.raises(Exception, match="without a class_name"):
        load_features(tmp_path / "nameless")


def test_half_written_cache_files_of_dead_processes_are_removed(tmp_path):
    import socket
    import subprocess
    import sys

    from spm_model.bench.feature_cache import CACHE_DIR, remove_stale_partials

    shard = tmp_path / "a.h5"
    cache = tmp_path / CACHE_DIR
    cache.mkdir()
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()
    host = socket.gethostname()
    stale = cache / f".a-x.npz.{host}.{dead}.partial"
    live = cache / f".a-y.npz.{host}.{os.getpid()}.partial"
    other = cache / f".a-z.npz.otherhost.{dead}.partial"
    for p in (stale, live, other):
        p.write_bytes(b"half")
    assert remove_stale_partials([shard]) == [stale]
    assert not stale.exists() and live.exists() and other.exists()


def test_only_grid_walks_give_path_neighbours(tmp_path):
    spec = 'class = "cup"\n[camera]\nsampler = "sphere"\nviews = 5\n'
    assert feature_cache.walks_in_steps({"spec": 'class = "cup"\n'}) is True            # the grid walk
    assert feature_cache.walks_in_steps({"source": "coil100"}) is True                  # an import: its own order
    assert feature_cache.walks_in_steps({"spec": spec}) is False                        # random views


def test_a_corrupt_shard_with_its_mtime_put_back_is_refused_not_served_from_the_cache(model_shards, tmp_path):
    """The cache is keyed by the shard's verified SHA-256, not its size and mtime: bit rot,
    `cp -p` or `rsync -t` of a damaged copy keep those."""
    from tests.helpers import flip_stored_byte

    folder = shutil.copytree(model_shards, tmp_path / "shards")
    config = FeatureConfig(ellipse="direct")
    load_features(folder, config)
    shard = find_shards(folder)[0]
    st = shard.stat()
    flip_stored_byte(shard, "pose")
    os.utime(shard, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert (shard.stat().st_size, shard.stat().st_mtime_ns) == (st.st_size, st.st_mtime_ns)
    with pytest.raises(ShardError, match=f"{shard}: field 'pose' fails its checksum"):
        load_features(folder, config)


def test_a_refused_run_leaves_no_cache_folder(model_shards, tmp_path):
    from tests.helpers import flip_stored_byte

    folder = shutil.copytree(model_shards, tmp_path / "shards", ignore=shutil.ignore_patterns(".spm-features"))
    flip_stored_byte(find_shards(folder)[-1], "rgb")
    with pytest.raises(ShardError, match="field 'rgb' fails its checksum"):
        load_features(folder, FeatureConfig(ellipse="direct"))
    assert not (folder / feature_cache.CACHE_DIR).exists()


def _one_shard_folder(model_shards, root, n=2):
    folder = root / "s"
    folder.mkdir(parents=True)
    for shard in sorted(model_shards.glob("*.h5"))[:n]:
        shutil.copy(shard, folder / shard.name)
    write_manifest(folder)
    return folder


def _same(a, b):
    return all(np.array_equal(getattr(a, k), getattr(b, k), equal_nan=a.arrays[k].dtype.kind == "f")
               for k in a.arrays)


@pytest.mark.slow  # features of two shards extracted four times
def test_a_damaged_swapped_or_cut_cache_file_is_extracted_again_never_read(model_shards, tmp_path):
    """The audit: one flipped byte in a .spm-features file was a BadZipFile traceback on every
    run, never rebuilt. Now the file is sealed (its shard, configuration and arrays): every
    damage is recomputed with one warning, and the table equals a cache-less run bit for bit."""
    from spm_data.errors import SpmWarning
    from spm_data.io.shards import shard_digest

    config = FeatureConfig(ellipse="direct")
    folder = _one_shard_folder(model_shards, tmp_path)
    truth = load_features(folder, config)                               # a run without any cache
    shards = find_shards(folder)
    files = [cache_path(s, config) for s in shards]
    good = files[0].read_bytes()
    # Every 401st byte flipped: refused (None) or, where zip ignores the byte, the same arrays.
    expected = feature_cache.read_cache(files[0], shard_digest(shards[0]), config)
    refused = 0
    for i in range(0, len(good), 401):
        bad = bytearray(good)
        bad[i] ^= 1 << (i % 8)
        files[0].write_bytes(bytes(bad))
        feature_cache._warned[0] = True                                 # said once; not the point here
        got = feature_cache.read_cache(files[0], shard_digest(shards[0]), config)
        if got is None:
            refused += 1
        else:
            assert all(np.array_equal(got[k], expected[k]) for k in expected), i
    assert refused > 0.9 * len(range(0, len(good), 401))
    other = files[1].read_bytes()
    at = good.index(b"query_vector.npy") + 400     # inside an array's bytes
    cases = {"cut short": (lambda: files[0].write_bytes(good[: len(good) // 2]), 1),
             "a flipped byte": (lambda: files[0].write_bytes(good[:at] + bytes([good[at] ^ 4]) + good[at + 1:]), 1),
             "swapped with another shard's": (lambda: (files[0].write_bytes(other), files[1].write_bytes(good)), 0)}
    for what, (damage, warned) in cases.items():
        files[0].write_bytes(good)
        files[1].write_bytes(other)
        damage()
        feature_cache._warned[0] = False
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            table = load_features(folder, config)
        said = [w for w in caught if issubclass(w.category, SpmWarning) and "feature cache" in str(w.message)]
        assert len(said) == warned, (what, [str(w.message) for w in caught])   # a sound file of another shard: silent
        assert _same(table, truth), what
        assert files[0].read_bytes() == good and files[1].read_bytes() == other, what   # rewritten whole


def test_progress_phase_starts_a_step_or_sets_a_plain_callables_total():
    """A Progress (spm_cli.support) starts a labelled step; a callable with only a
    ``total`` (benchmarks/fig5.py's log lines, a tqdm bar) gets a new total; None is nothing."""
    from spm_model.bench.feature_cache import progress_phase

    class Stepped:
        def phase(self, label, total, unit):
            self.step = (label, total, unit)

    class Counted:
        total = None

    stepped, counted = Stepped(), Counted()
    progress_phase(stepped, "features", 48)
    progress_phase(counted, "features", 48)
    progress_phase(None, "features", 48)
    assert stepped.step == ("features", 48, "frame") and counted.total == 48
