"""Progress of long steps, for the library, the command line and scripts alike (no click): a bar on
a terminal, a line every ``$SPM_PROGRESS_EVERY`` seconds (default 10) elsewhere. Library calls take
any ``progress`` callable fed count deltas; this is the one the programs and the benchmarks hand them."""

from __future__ import annotations

import os
import sys
import threading
import time


def progress_every() -> float:
    """Seconds between progress lines off a terminal: $SPM_PROGRESS_EVERY, default 10."""
    try:
        return max(0.01, float(os.environ.get("SPM_PROGRESS_EVERY") or 10))
    except ValueError:
        return 10.0


def _duration(seconds: float) -> str:
    """"42 s", "1 min 31 s", "2 h 5 min"."""
    s = int(round(seconds))
    if s < 60:
        return f"{s} s"
    return f"{s // 60} min {s % 60} s" if s < 3600 else f"{s // 3600} h {s % 3600 // 60} min"


def _count(n) -> str:
    return f"{n:,}" if float(n).is_integer() else f"{n:,.1f}"


class Progress:
    """Progress of a long step, fed count deltas (negative when a crashed shard's frames are taken
    back): a tqdm bar on a terminal; elsewhere (a log, a pipe) one line on stderr every EVERY
    seconds, the first after EVERY seconds (none for a shorter run), e.g.
    ``render: 1,234/5,000 frames, 41.2 frames/s, 1 min 31 s left`` (no "left" without a total). The
    time left is that of the rate up to the last count, less the time since it: between the ends of
    a few long items (splits) it counts down, and once it runs out it is left out, never a guess
    that grows while nothing ends.

    ``label`` None: "progress" (spm_cli.support.Progress names the running command instead).
    EVERY: None reads $SPM_PROGRESS_EVERY (default 10 s). ``phase(label, total, unit)`` starts
    a command's next step (a new count); setting ``total`` starts a new count of the same step;
    a phase with ``unit`` None counts nothing ("report: 25 s so far")."""

    EVERY = None

    def __init__(self, unit="frame", label=None, total=None, stream=None):
        self.stream = stream if stream is not None else sys.stderr
        self.every = self.EVERY or progress_every()
        self._lock, self._stop = threading.Lock(), threading.Event()
        self._start(label or "progress", total, unit)
        self.bar = self._ticker = None
        if getattr(self.stream, "isatty", lambda: False)():
            from tqdm import tqdm

            self.bar = tqdm(total=total, unit=unit or "it", desc=self.label, dynamic_ncols=True, file=self.stream)
        else:
            self._ticker = threading.Thread(target=self._tick, name="spm-progress", daemon=True)
            self._ticker.start()

    def _start(self, label, total, unit):
        with self._lock:
            self.label, self._total, self.unit, self.done = label, total, unit, 0
            self.started = self.counted = time.monotonic()   # counted: when the count last grew

    @property
    def total(self):
        return self._total

    @total.setter
    def total(self, value):
        self.phase(self.label, value, self.unit)

    def phase(self, label, total=None, unit="frame"):
        """Start the next step: ``label``, ``total`` (None: unknown) of ``unit``, counted from 0."""
        self._start(label, total, unit)
        if self.bar is not None:
            self.bar.unit, self.bar.desc = unit or "it", label
            self.bar.reset(total=total)

    def __call__(self, n=1):
        with self._lock:
            self.done += n
            if n > 0:
                self.counted = time.monotonic()
        if self.bar is not None:
            self.bar.update(n)

    def line(self) -> str:
        """The progress line as it stands (what is printed off a terminal)."""
        with self._lock:
            label, unit, total, done = self.label, self.unit, self._total, max(self.done, 0)
            now = time.monotonic()
            elapsed, counting = now - self.started, self.counted - self.started
        if unit is None:
            return f"{label}: {_duration(elapsed)} so far"
        units = unit + ("es" if unit.endswith(("s", "x", "ch", "sh")) else "s")
        rate = done / elapsed if elapsed > 0 else 0.0
        speed = (f"{rate:,.1f} {units}/s" if rate >= 0.1 else f"0 {units}/s" if rate == 0 else
                 f"{rate * 60:.1f} {units}/min")
        # Time left at the rate of the counts so far, less the time since the last one: it counts down
        # while a long item runs (a split) instead of growing, and is not guessed once that has run out.
        left = (total - done) * counting / done - (now - self.counted) if total and 0 < done < total else 0
        left = f", {_duration(left)} left" if counting > 0 and left >= 0.5 else ""
        return f"{label}: {_count(done)}{f'/{_count(total)}' if total is not None else ''} {units}, {speed}{left}"

    def _tick(self):
        while not self._stop.wait(self.every):
            try:
                self.stream.write(self.line() + "\n")
                self.stream.flush()
            except (OSError, ValueError):   # the stream went away (a closed pipe): stop saying
                return

    def write(self, message: str):
        """A log line on stdout that does not break the bar."""
        if self.bar is not None:
            self.bar.write(message)
        else:
            print(message, flush=True)

    def close(self):
        self._stop.set()
        if self._ticker is not None and self._ticker is not threading.current_thread():
            self._ticker.join()
        if self.bar is not None:
            self.bar.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def stage(label: str, total=None, unit: str | None = None) -> Progress:
    """A script's step: ``label`` on stderr now, and a :class:`Progress` of it (a context manager)
    to feed counts of ``unit``, or, with ``unit`` None, whose lines say how long the step has run."""
    print(label, file=sys.stderr, flush=True)
    return Progress(unit, label, total)


def tracked(items, label: str, unit: str = "item", total=None):
    """Yield ``items`` after a stage line, with a :class:`Progress` of them (for loops in scripts)."""
    with stage(label, total if total is not None else len(items) if hasattr(items, "__len__") else None, unit) \
            as progress:
        for item in items:
            yield item
            progress(1)
