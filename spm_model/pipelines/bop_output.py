"""``--bop-results DIR`` of ``spm train`` and ``spm evaluate``: every method's estimates as a BOP
results file ``DIR/{method}_{dataset}-{split}.csv`` (spm_data/formats/bop/results.py), the frames
numbered as ``spm-data export bop`` numbers them (spm_data/formats/bop/ids.py).

``spm evaluate``: the model's estimate of every frame of the folder. ``spm train``: each test
frame's estimate in the first run (seed 0) of the protocol, every split of it (under loco each
frame is tested once; under views and interleaved only the held-out frames have rows; under
offgrid the frames of the --test folder, numbered as the export of that folder). The estimates are
those of run 1: the methods are fitted again here on run 1's splits with run 1's seed (on one BLAS
thread, as the benchmark's workers are), which gives run 1's predictions.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spm_data.errors import SpmError
from spm_data.io.outputs import check_out_name, unwritable
from spm_data.io.shards import read_attrs


@dataclass(frozen=True)
class BopOutput:
    """Where and how to write the results files: ``folder`` (--bop-results), ``dataset``
    (--bop-dataset), ``split`` (--bop-split), ``ids_from`` (--bop-ids-from: an earlier export whose
    obj_ids to keep, as export bop --ids-from)."""
    folder: Path
    dataset: str = "spm"
    split: str = "test"
    ids_from: Path | None = None

    def check(self, *shard_folders, allow_partial: bool = False) -> None:
        """SpmError (one line) for a bad name, a folder that cannot be one or cannot be written (a
        read-only place, a name too long), or a shard folder whose frames an export would not number
        (shards in its subfolders), before any work."""
        from spm_data.formats.bop.results import result_file_name

        for shards in (f for f in shard_folders if f is not None):
            _check_one_folder(Path(shards), allow_partial)

        result_file_name("m", self.dataset, self.split)
        folder = check_out_name(Path(self.folder), "--bop-results")   # first: a name too long cannot be looked up
        if folder.exists() and not folder.is_dir():
            raise SpmError(f"--bop-results {folder}: expected a folder, got a file; give a folder for the .csv files")
        problem = unwritable(folder)   # now, not after the features and the fits (issue 47)
        if problem:
            state = "is a file" if problem[1] == "file" else "is read-only"
            raise SpmError(f"--bop-results {folder}: cannot write there: {problem[0]} {state}; give a writable folder")
        if self.ids_from is not None and not Path(self.ids_from).exists():
            raise SpmError(f"--bop-ids-from {self.ids_from}: no such export; give the folder export bop wrote "
                           "(or its objects.json)")

    def write(self, shards, table, predictions: dict, allow_partial: bool = False) -> list[Path]:
        """One results file per method of ``predictions`` ({method: (table rows, (n, 6) labels)}) of the
        frames of the shard folder ``shards`` (the rows of ``table``, a FeatureTable, are mapped to
        its frame order). Returns the files written."""
        from spm_data.formats.bop.ids import frame_ids
        from spm_data.formats.bop.results import pose_rows, result_file_name, save_bop_results

        ids = frame_ids(shards, self.ids_from, allow_partial=allow_partial)
        where = frame_positions(shards, table, allow_partial)
        folder = Path(self.folder)
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise SpmError(f"--bop-results {folder}: cannot create it ({exc.strerror or exc}); give a writable "
                           "folder") from None
        written = []
        for method, (rows, labels) in predictions.items():
            rows = np.asarray(rows, dtype=np.int64)
            if (where[rows] < 0).any():
                raise SpmError(f"--bop-results: {int((where[rows] < 0).sum())} frames are not in {shards}'s "
                               "manifest (a subfolder's?); expected one shard folder, as export bop reads it; "
                               "give that folder")
            path = folder / result_file_name(method, self.dataset, self.split)
            written.append(save_bop_results(path, pose_rows(ids, labels, where[rows])))
        return written


def _check_one_folder(shards: Path, allow_partial: bool) -> None:
    from spm_data.io.folders import find_folders, open_folder

    if shards.is_file():
        return
    found = [f for f in find_folders(shards) if f != shards]
    if found and not any(shards.glob("*.h5")):
        raise SpmError(f"--bop-results: {shards} holds its shards in subfolders ({found[0].name}/…), which export "
                       "bop does not number; give one shard folder (merge them with spm-data merge first)")
    open_folder(shards, allow_partial=allow_partial)


def frame_positions(shards, table, allow_partial: bool = False) -> np.ndarray:
    """(n,) int64: each row of ``table`` (its ``shard`` and ``frame``) as a position in the frame
    order of the shard folder ``shards`` (manifest order, then frame index); -1 for a row of
    another folder."""
    from spm_data.io.folders import open_folder

    start, offset = {}, 0
    for shard in open_folder(shards, allow_partial=allow_partial).shards:
        start[str(Path(shard).resolve())] = offset
        offset += int(read_attrs(shard)["frames"])
    first = {s: start.get(str(Path(s).resolve()), -1) for s in set(table.shard.tolist())}
    base = np.asarray([first[s] for s in table.shard.tolist()], dtype=np.int64)
    return np.where(base >= 0, base + np.asarray(table.frame, dtype=np.int64), -1)


def first_run_predictions(table, protocol: str, model_params: dict, builtins=None, estimators=None,
                          train_occluded: bool | None = None, timeout: float | None = None) -> dict:
    """{method: (test rows of ``table``, (n, 6) labels)} of the first run of ``protocol``: every split
    of run 1, its methods fitted and asked as the benchmark does (protocols.split_job). A method
    declined in a split has no rows there (NaN labels)."""
    from threadpoolctl import threadpool_limits

    from spm_model.bench.feature_cache import memo_folder
    from spm_model.bench.fitting import builtin_classes, fit_predict
    from spm_model.bench.protocols import splits, training_rows

    occluded = (protocol != "offgrid") if train_occluded is None else bool(train_occluded)
    memo = memo_folder(table.shard[0], model_params["features"]) if len(table) else None
    methods = list(builtin_classes(model_params, builtins)) + list(estimators or {})
    out: dict = {}
    with threadpool_limits(limits=1, user_api="blas"):
        for _, train, test in splits(table, protocol, seed=0):
            train = training_rows(table, train, occluded)
            if len(test) == 0 or len(train) == 0:
                continue
            predictions, _, _ = fit_predict((0, model_params, builtins, estimators), table, train, test, seed=0,
                                            timeout=timeout, memo=memo)
            for name in methods:
                pred = predictions.get(name, np.full((len(test), 6), np.nan))
                rows, labels = out.get(name, (np.zeros(0, np.int64), np.zeros((0, 6))))
                out[name] = (np.r_[rows, test], np.r_[labels, pred])
    return out
