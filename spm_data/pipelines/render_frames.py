"""One rendered frame, as a shard stores it: the spec's draws and distractors, the
render, the background, and the opt-in outputs; and the pipeline that takes frames from
the renderer's thread to the shard (spm_data.pipelines.render_jobs streams them into shards).
"""

from __future__ import annotations

import os
import queue
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from spm_data.core.backgrounds import background_image, composite
from spm_data.core.distractors import place_distractors
from spm_data.core.randomize import frame_draws, frame_rng, lights_width
from spm_data.core.raster import object_coords
from spm_data.errors import ShardError
from spm_data.io.shards import FIELDS, OPTIONAL_FIELDS
from spm_data.io.shards.chunks import encode_chunk
from spm_data.jobs.executor import WORKER_CORES


class FrameMaker:
    """Renders frames of one spec with ``renderer``: ``image_fields`` per frame,
    and the per-frame labels ``make`` returns besides the camera path's."""

    def __init__(self, spec, renderer):
        self.spec, self.renderer = spec, renderer
        self.render_seconds = 0.0  # in renderer.render (its readback included), on the renderer's thread
        self.distractors = spec.distractors.count > 0
        self.randomized = spec.randomize.enabled
        outputs = spec.outputs
        self.image_fields = ("rgb", "depth", "mask") + (("visible_mask",) if self.distractors else ()) + tuple(
            f for f in ("instances", "normals", "coords") if getattr(outputs, f))

    def bytes_per_pixel(self) -> int:
        """Raw bytes a frame's image fields take per pixel."""
        table = {**FIELDS, **OPTIONAL_FIELDS}
        return sum(np.dtype(table[f][0]).itemsize * (3 if table[f][1][-1] == 3 else 1) for f in self.image_fields)

    def scene(self, mesh, instance: int, path_index: int, R, t) -> tuple:
        """(draws, placement) of frame (``instance``, ``path_index``): its FrameDraws (None
        without ``[randomize]``) and its PlacedDistractors (None without ``[distractors]``);
        the renderer draws it as ``render(R, t, draws, placement.distractors)``."""
        draws = frame_draws(self.spec, instance, path_index, self.renderer.K) if self.randomized else None
        K = draws.K if draws is not None else self.renderer.K
        placement = place_distractors(self.spec, mesh, R, t, K, instance, path_index) if self.distractors else None
        return draws, placement

    def make(self, mesh, instance: int, path_index: int, R, t) -> tuple[dict, dict]:
        """(images {field: one frame's array}, labels {field: one frame's value}) of frame
        (``instance``, ``path_index``), the target ``mesh`` posed by ``R``, ``t``."""
        return self.finish(self.render(mesh, instance, path_index, R, t), instance, path_index, R, t)

    def render(self, mesh, instance: int, path_index: int, R, t) -> tuple:
        """The part of ``make`` that needs the renderer's thread: (draws, placement, the
        renderer's arrays) of the frame, for ``finish``."""
        draws, placement = self.scene(mesh, instance, path_index, R, t)
        started = time.perf_counter()
        out = self.renderer.render(R, t, draws=draws, distractors=placement.distractors if placement else ())
        self.render_seconds += time.perf_counter() - started
        return draws, placement, out

    def finish(self, rendered: tuple, instance: int, path_index: int, R, t) -> tuple[dict, dict]:
        """The rest of ``make``, on any thread: the background composited, the opt-in outputs
        and the labels of a frame ``render`` drew (its arrays are new every frame)."""
        spec = self.spec
        draws, placement, out = rendered
        K = draws.K if draws is not None else self.renderer.K
        kind = draws.background if draws is not None else spec.background.kind
        rgb = out["rgb"]
        if kind != "black":
            background = background_image(spec, frame_rng(spec, instance, path_index, "background"), kind)
            rgb = composite(rgb, out["alpha"], background)
        images = {"rgb": rgb, "depth": out["depth"], "mask": out["mask"]}
        labels = {"K": K}
        if draws is not None:
            labels.update(draws.labels(lights_width(spec)))
        if placement is not None:
            images["mask"] = placement.amodal.astype(np.uint8)
            # Hidden means something drawn in front: an amodal pixel the render left empty (its
            # rasteriser and ours split a silhouette edge differently) is visible, as BOP counts it.
            images["visible_mask"] = images["mask"] & (out["mask"] | (out["depth"] == 0))
            labels.update(self._distractor_labels(placement, images))
        for field in ("instances", "normals"):
            if field in self.image_fields:
                images[field] = out[field]
        if "coords" in self.image_fields:
            images["coords"] = object_coords(out["depth"], out["mask"] > 0, K, R, t).astype(np.float16)
        return images, labels

    def _distractor_labels(self, placement, images) -> dict:
        n = self.spec.distractors.count
        mesh = np.full(n, -1, np.int64)
        Rs, ts, sizes = np.zeros((n, 3, 3)), np.zeros((n, 3)), np.zeros(n)
        for k, d in enumerate(placement.distractors):
            mesh[k], Rs[k], ts[k], sizes[k] = d.mesh_index, d.R, d.t, d.size
        area = int(images["mask"].sum())
        seen = int(images["visible_mask"].sum())
        return {"visible_target": np.float32(placement.visible_target), "distractor_mesh": mesh,
                "distractor_R": Rs, "distractor_t": ts, "distractor_size": sizes,
                "occlusion_fraction": np.float32(1.0 - seen / area if area else 0.0)}


def pipeline_threads() -> int:
    """Threads of a FramePipeline: this worker's share of the cores (the executor's
    SPM_WORKER_CORES), at least 2 (compression and compositing overlap the render), at most 16."""
    cores = os.environ.get(WORKER_CORES, "")
    share = int(cores) if cores.isdigit() else len(os.sched_getaffinity(0))
    return max(2, min(16, share))


PIPELINE_NICE = 10
# The GIL's switch interval while a pipeline runs (Python's default is 5 ms): the renderer's thread,
# back from a GL call that let go of the GIL, waits up to this long for a pipeline thread running
# Python (h5py, numpy's small steps) to hand it back; at 128x128 a frame takes about 5 ms.
SWITCH_SECONDS = 0.0005


def _behind_the_renderer() -> None:
    """This thread (a pipeline's) yields the cores to the renderer's thread and the GL driver's
    (llvmpipe rasterises on threads of its own): niceness PIPELINE_NICE (or its own, if higher),
    on Linux a thread's own (setpriority on its thread id), so compression fills the cores the
    renderer leaves idle instead of slowing it down. Raising niceness needs no privilege; where
    it fails, nothing changes."""
    try:
        me = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, me, max(PIPELINE_NICE, os.getpriority(os.PRIO_PROCESS, me)))  # never up
    except (AttributeError, OSError):
        pass


class FramePipeline:
    """A shard's frames from the renderer's thread to the writer: ``put(task)`` hands a frame's
    finishing (``task()`` -> (images, labels): compositing, the opt-in outputs) to a pool of
    threads, which also compress its image fields (encode_chunk; zlib lets go of the GIL), and
    one writer thread stores the chunks in the order write_images stores a block (``block``
    frames, field by field), so the shard is the serial path's bytes. The renderer's thread
    only renders. At most ``ahead`` frames are being finished or compressed (put waits), so a
    worker holds a few frames' arrays and a block's compressed chunks, whatever the shard's
    length. ``close()`` waits for every frame to be stored and returns their labels, in order;
    leaving the block otherwise stops the threads. ``seconds``: busy time per stage."""

    def __init__(self, writer, block: int, threads: int = 2, ahead: int = 0):
        self.writer, self.block = writer, max(1, int(block))
        self.seconds = {"composite": 0.0, "compress": 0.0, "write": 0.0}
        self._labels, self._put, self._error = [], 0, None
        self._lock = threading.Lock()
        self._room = threading.Semaphore(max(1, ahead or 2 * threads))
        self._queue = queue.SimpleQueue()  # Futures in frame order, for the writer thread; None: stop
        self._pool = ThreadPoolExecutor(max_workers=threads, initializer=_behind_the_renderer)
        self._thread = threading.Thread(target=self._store_all, name="spm-shard-writer", daemon=True)
        self._thread.start()

    def put(self, task) -> None:
        """The next frame: ``task()`` runs on the pool; ShardError or the writer's own error,
        raised here, when storing a frame before it failed."""
        self._room.acquire()  # freed as each frame is compressed, whatever happens to it
        if self._error is not None:
            self._room.release()
            raise self._error
        self._queue.put(self._pool.submit(self._finish, task))
        self._put += 1

    def _finish(self, task) -> tuple:
        try:
            started = time.perf_counter()
            images, labels = task()
            made = time.perf_counter()
            missing = [f for f in self.writer.images if f not in images]
            if missing:
                raise ShardError(f"shard field {missing[0]!r}: the frame has no such image")
            chunks = {f: encode_chunk(self.writer.check_frame(f, images[f])) for f in self.writer.images}
            self._add(composite=made - started, compress=time.perf_counter() - made)
            return chunks, labels
        finally:
            self._room.release()

    def _add(self, **seconds) -> None:
        with self._lock:
            for stage, value in seconds.items():
                self.seconds[stage] += value

    def _store_all(self) -> None:
        """The writer thread: blocks of frames, each field's chunks in frame order."""
        _behind_the_renderer()
        try:
            for start in range(0, self.writer.frames, self.block):
                block = []
                for index in range(start, min(start + self.block, self.writer.frames)):
                    future = self._queue.get()
                    if future is None:
                        return
                    chunks, labels = future.result()
                    self._labels.append(labels)
                    block.append(chunks)
                    self._store(self.writer.images[0], index, chunks)  # the first field as it comes
                for field in self.writer.images[1:]:
                    for k, chunks in enumerate(block):
                        self._store(field, start + k, chunks)
        except BaseException as exc:  # noqa: BLE001 - raised on the renderer's thread (put, close)
            self._error = exc

    def _store(self, field: str, index: int, chunks: dict) -> None:
        started = time.perf_counter()
        self.writer.store_chunk(field, index, chunks[field])
        self._add(write=time.perf_counter() - started)

    def close(self) -> list:
        """Wait for every frame to be stored; their labels, in frame order."""
        if self._put != self.writer.frames:
            raise ShardError(f"{self.writer.path.name}: {self._put} of {self.writer.frames} frames given; not written")
        self._thread.join()
        self._pool.shutdown()
        if self._error is not None:
            raise self._error
        return self._labels

    def __enter__(self):
        self._switch = sys.getswitchinterval()
        sys.setswitchinterval(min(self._switch, SWITCH_SECONDS))
        return self

    def __exit__(self, *exc):
        try:
            if self._thread.is_alive():  # left early: the writer thread stops at the next frame it takes
                self._queue.put(None)
                self._pool.shutdown(cancel_futures=True)
                self._thread.join()
            self._pool.shutdown()
        finally:
            sys.setswitchinterval(self._switch)
        return False
