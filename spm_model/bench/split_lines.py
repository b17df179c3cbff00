"""The line ``spm train`` prints as each split of each run ends (bench/protocols.py), in the
order of the jobs, whatever order the workers finish them in, and naming the same declines as
the summary: a method reused from run 1 (fitted there only) is declined in a later run too
when it declined in run 1, and the line says so.

    run 1: loco test cup (1,500 train / 300 test frames); declined: n3m, smm
    run 2: loco test cup (1,500 train / 300 test frames); declined: n3m (reused from run 1), smm
"""

from __future__ import annotations

from spm_model.bench.jobs import SplitJob


class SplitLines:
    """Fed (job, output) as jobs finish, in any order (output None: the job failed, no line);
    says each split job's line through ``report`` once every job before it has finished.
    jobs: bench/protocols.py's jobs, FinalJobs for the final models (no line), else SplitJobs
    (source, protocol, run, split index, ...)."""

    def __init__(self, jobs: list, report):
        self.jobs, self.report = list(jobs), report
        self.finished: dict = {}   # job position -> its output (None: failed)
        self.next = 0              # the first position whose line is not said yet

    def _position(self, job) -> int:
        for i, known in enumerate(self.jobs):
            if known is job:
                return i
        return self.jobs.index(job)   # an executor that handed back a copy

    def __call__(self, job, output) -> None:
        self.finished[self._position(job)] = output
        while self.next in self.finished:
            job, output = self.jobs[self.next], self.finished[self.next]
            if output is not None and isinstance(job, SplitJob) and len(output[2]):
                self.report(split_line(job, output, self._first_run(job)))
            self.next += 1

    def _first_run(self, job):
        """Run 1's output of ``job``'s split (said before it: run 1's jobs come first), or None."""
        if not job.run:
            return None
        for i, known in enumerate(self.jobs[:self.next]):
            if isinstance(known, SplitJob) and known.run == 0 and known.index == job.index:
                return self.finished.get(i)
        return None


def split_line(job, output, first=None) -> str:
    """``run R: PROTOCOL test WHAT (N train / M test frames)`` and the methods declined in it: those
    that ran in it and, in a later run, those reused from ``first`` (run 1's output of the split)
    that declined there, marked as reused."""
    tested, n_train, test, errors, notes = output
    ran = notes["featured"]
    reused = [m for m in (first[4]["declined"] if first is not None else {}) if m not in ran]
    declined = [m for m in notes["declined"] if m not in reused]
    text = f"run {job.run + 1}: {job.protocol} test {tested} ({n_train} train / {len(test)} test frames)"
    if job.run and not errors:   # nothing ran: every method is reused
        return text + "; every method's predictions reused from run 1" + (
            f" (declined there: {', '.join(reused)})" if reused else "")
    names = [f"{m} (reused from run 1)" for m in reused] + declined
    return text + (f"; declined: {', '.join(names)}" if names else "")
