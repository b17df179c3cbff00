"""Estimator code in a process of its own. Each split's methods are constructed, fitted and asked
in a fresh child process, started for the split and ended after it (``python -c``, a new session:
the terminal's Ctrl-C never reaches it; it exits when its parent is gone). The child receives the
training frames (spm_model/base/frames.py ``Frames``) with their poses, then the test frames as a
camera gives them (``CameraFrames``: image, visible mask, K) in the split's seeded random order,
and nothing else: no test pose, no other split's frames, no feature table. The process that
holds the labels (a benchmark worker) only starts it, sends those frames and reads back, without
unpickling anything, arrays of numbers (``np.load(allow_pickle=False)``) and one-line reasons;
scoring happens there, where estimator code never runs.

A method whose call raises anything (``SystemExit`` and ``KeyboardInterrupt`` included), whose
process exits or is killed, or whose plug-in call runs past ``timeout`` seconds (the child is then
killed), is *declined* with that reason; the caller starts another child for the methods left.
"""

from __future__ import annotations

import functools
import io
import json
import os
import subprocess
import sys
import threading
import time
from multiprocessing.connection import Connection

import numpy as np

DEFAULT_TIMEOUT = 3600.0   # seconds a plug-in's call (construct + fit, or one predict) may take
MAX_MESSAGE = 1 << 30      # bytes of one message from the child, at most (predictions are far smaller)
READY = b"ready"            # the child's first message, before any plug-in code runs
MESSAGE_SECONDS = 600.0    # seconds a message begun may take to arrive whole, where no time limit is set


# OpenCV's AVX-512 code families: {name in OPENCV_CPU_DISABLE: its cv::CpuFeatures id}.
OPENCV_AVX512 = {"AVX512F": 13, "AVX512-SKX": 256, "AVX512-COMMON": 257, "AVX512-KNL": 258, "AVX512-KNM": 259,
                 "AVX512-CNL": 260, "AVX512-CLX": 261, "AVX512-ICL": 262}


@functools.lru_cache(maxsize=1)
def method_environment() -> dict:
    """The environment a method's process runs in, so that its results are the same on every x86-64
    machine with AVX2, whatever else the CPU has: OpenBLAS's Haswell kernels (it picks its kernels
    by CPU: SMM's estimate of one frame in 48 and SIFT + PnP's in the 9th decimal changed between
    its Haswell and SkylakeX kernels), and numpy's and OpenCV's AVX2 code where the CPU has AVX-512
    (numpy's AVX-512 loops changed the template matcher's estimates of 7 frames in 48 by 1e-16).
    Elsewhere (no AVX2, another architecture), nothing is pinned."""
    try:
        with open("/proc/cpuinfo") as fh:
            flags = next((line.split(":", 1)[1].split() for line in fh if line.startswith("flags")), [])
    except OSError:
        flags = []
    if "avx2" not in flags:
        return {}
    try:
        from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__
    except ImportError:   # numpy < 2
        from numpy.core._multiarray_umath import __cpu_dispatch__, __cpu_features__
    import cv2

    numpy_avx512 = [f for f in __cpu_dispatch__ if f.startswith("AVX512") and __cpu_features__.get(f)]
    opencv_avx512 = [name for name, i in OPENCV_AVX512.items() if cv2.checkHardwareSupport(i)]  # others warn
    return {"OPENBLAS_CORETYPE": "Haswell", **({"NPY_DISABLE_CPU_FEATURES": " ".join(numpy_avx512)} if numpy_avx512
                                               else {}),
            **({"OPENCV_CPU_DISABLE": ",".join(opencv_avx512)} if opencv_avx512 else {})}


class Lost(Exception):
    """The child ended (or was ended) while running the method ``name``: ``why`` it is declined."""

    def __init__(self, name: str, why: str):
        super().__init__(why)
        self.name, self.why = name, why


def encode(header: dict, arrays=()) -> list:
    """A reply as bytes messages: a JSON header, then each array as a .npy (no pickle)."""
    out = [json.dumps({**header, "arrays": len(arrays)}).encode()]
    for a in arrays:
        buf = io.BytesIO()
        np.save(buf, np.asarray(a), allow_pickle=False)
        out.append(buf.getvalue())
    return out


class EstimatorProcess:
    """The parent's end of one child: send it Python objects (the parent's own, trusted by the
    child), read its replies as headers and plain arrays."""

    def __init__(self, work: str = "spm_model.bench.isolated_child:serve"):
        """``work``: what the child runs ('MODULE:FUNCTION' taking the pipe's two ends)."""
        down_r, down_w = os.pipe()   # parent -> child
        up_r, up_w = os.pipe()       # child -> parent
        code = (f"import sys; sys.path[:] = {sys.path!r}; from spm_model.bench.isolated_child import child_main; "
                f"child_main({down_r}, {up_w}, {os.getpid()}, {work!r})")   # our sys.path before any import
        self.started_as = (work, list(sys.path), dict(os.environ))   # what fresh() compares
        self.proc = subprocess.Popen([sys.executable, "-c", code], pass_fds=(down_r, up_w), start_new_session=True,
                                     stdin=subprocess.DEVNULL, env={**os.environ, **method_environment()})
        os.close(down_r)
        os.close(up_w)
        self.down = Connection(down_w, readable=False)
        self.up = Connection(up_r, writable=False)
        self.ready = False   # the child says READY once started: its start is not the plug-in's time

    def send(self, message) -> None:
        try:
            self.down.send(message)
        except OSError:
            pass   # it died: the next reply says how

    def reply(self, name: str, stage: str, limit: float | None, tick=None) -> tuple:
        """(header, arrays) of the child's next reply, about ``name``; Lost when it does not come:
        the child exited, sent something else, or took longer than ``limit`` seconds (it is then
        killed). ``tick()`` is called about once a second while waiting (the caller's chance to
        stop on Ctrl-C). The clock starts once the child has started (Python and our modules
        loaded: seconds on a busy machine, and no plug-in code)."""
        if not self.ready:
            if self._next(name, stage, time.monotonic(), None, tick) != READY:
                self.close()
                raise Lost(name, f"{stage}the method's process sent something that is not its reply")
            self.ready = True
        start = time.monotonic()
        try:
            header = json.loads(self._next(name, stage, start, limit, tick))
        except ValueError:
            header = None
        if not isinstance(header, dict) or header.get("name") != name or not isinstance(header.get("arrays"), int):
            self.close()
            raise Lost(name, f"{stage}the method's process sent something that is not its reply")
        arrays = []
        for _ in range(header["arrays"]):
            try:
                arrays.append(np.load(io.BytesIO(self._next(name, stage, start, limit, tick)), allow_pickle=False))
            except ValueError:
                self.close()
                raise Lost(name, f"{stage}the method's process sent something that is not an array") from None
        return header, arrays

    def _next(self, name: str, stage: str, start: float, limit: float | None, tick) -> bytes:
        """The child's next message (bytes), waited for as ``reply`` says."""
        while not self.up.poll(1.0):
            if tick is not None:
                tick()
            if self.proc.poll() is not None and not self.up.poll(0):
                raise Lost(name, f"{stage}the method's process ended ({self._exit_text()}) without a result")
            if limit is not None and time.monotonic() - start > limit:
                self.close()
                raise Lost(name, f"{stage}took longer than the time limit (--timeout {limit:g} s)")
        # A message begun but not finished would block the read: the time limit (or, without one,
        # MESSAGE_SECONDS: the child writes each message whole) kills the child then.
        left = MESSAGE_SECONDS if limit is None else max(0.0, start + limit - time.monotonic()) + 1.0
        timer = threading.Timer(left, self.proc.kill)
        try:
            timer.start()
            return self.up.recv_bytes(MAX_MESSAGE)
        except (EOFError, OSError):
            self.close()
            raise Lost(name, f"{stage}the method's process ended ({self._exit_text()}) without a result") from None
        finally:
            timer.cancel()

    def _exit_text(self) -> str:
        code = self.proc.wait()
        return f"killed by signal {-code}" if code < 0 else f"exit code {code}"

    def close(self) -> None:
        """End the child: asked to, then killed if it has not ended within a second."""
        self.send(None)
        for end in (self.down, self.up):
            end.close()
        try:
            self.proc.wait(timeout=1.0)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


_SPARE: list = [None]   # a child started for the next split: it has imported the methods and holds nothing


def fresh_process() -> EstimatorProcess:
    """A fresh child for a split's methods: the spare one started when the last split began (its
    start-up, Python and the methods' imports, overlapped that split's work), when it was started as
    this one would be (same sys.path and environment) and is alive; else a new one. Each call starts
    the spare for the next. A spare has received nothing: it is as fresh as a new process."""
    spare, _SPARE[0] = _SPARE[0], None
    wanted = ("spm_model.bench.isolated_child:serve", list(sys.path), dict(os.environ))
    if spare is not None and (spare.started_as != wanted or spare.proc.poll() is not None):
        spare.close()
        spare = None
    child = spare or EstimatorProcess()
    _SPARE[0] = EstimatorProcess()
    return child
