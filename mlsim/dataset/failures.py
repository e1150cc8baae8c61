"""Jobs that fail in :func:`mlsim.dataset.executors.map_unordered` with ``on_failure="record"``: the
failure as a value (:class:`JobFailed`), and the local pool that survives a worker killed mid-job
(issue 39: a dataset goes on past an episode that raises or whose process the out-of-memory killer
ends).

Standard library only, as :mod:`mlsim.dataset.workers` (the worker side it shares with
:mod:`mlsim.dataset.executors`, which imports this module; this one never imports executors): the
spawned workers must not import numpy before their thread limits are set.
"""

from __future__ import annotations

import signal
from collections.abc import Iterator
from concurrent.futures import FIRST_COMPLETED, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any

from mlsim.dataset.workers import END, LOCAL_JOBS_PER_WORKER, POLL_S, job_error, last_line, local_pool, run_local_job

__all__ = ["JobFailed", "failure_from_traceback", "killed_failure", "map_local_recording"]


@dataclass(frozen=True)
class JobFailed:
    """The result of a job that did not finish (``on_failure="record"``).

    Attributes
    ----------
    kind : str
        ``"error"``: the job raised in a live worker; ``"killed"``: its worker process ended while it
        ran (a signal such as the kernel's out-of-memory killer's SIGKILL, or an exit).
    error_type : str
        The exception's type name, or the signal's name (``"SIGKILL"``), or ``"exit 3"``.
    message : str
        The exception's message, or why the worker ended.
    traceback : str
        The worker's traceback ("" for a killed worker).
    """

    kind: str
    error_type: str
    message: str
    traceback: str = ""

    @property
    def reason(self) -> str:
        """One line: ``"SolverError: ..."`` or ``"killed: ..."``."""
        return f"{self.error_type}: {self.message}" if self.kind == "error" else f"killed: {self.message}"


def failure_from_traceback(payload: str) -> JobFailed:
    """A JobFailed from a worker's traceback text: its last line is "Type: message"."""
    last = last_line(payload)
    error_type, _, message = last.partition(": ")
    return JobFailed("error", error_type.rsplit(".", 1)[-1] or "Exception", message, payload)


def killed_failure(exitcode: int | None) -> JobFailed:
    if exitcode is not None and exitcode < 0:
        try:
            name = signal.Signals(-exitcode).name
        except ValueError:
            name = f"signal {-exitcode}"
        why = f"its worker process was killed by {name}" + (
            " (the kernel's out-of-memory killer sends it, as does kill -9)" if name == "SIGKILL" else "")
        return JobFailed("killed", name, why)
    return JobFailed("killed", f"exit {exitcode}", f"its worker process exited with code {exitcode} before the job finished")


def map_local_recording(fn, items, workers, env, threads, worker_setup, setup_args) -> Iterator[tuple[Any, Any]]:
    """:func:`mlsim.dataset.executors.map_unordered`'s local pool with ``on_failure="record"``: failures are yielded, a broken pool is replaced.

    Which job killed the pool: each worker puts (pid, job number) on a queue as a job starts; when
    the pool breaks, ``concurrent.futures`` SIGTERMs its other workers, so the job that started on a
    worker that ended otherwise (SIGKILL, SIGSEGV, an exit code) is the one that died. The jobs lost
    with it are run again; a break with no such job (an outside SIGTERM) blames every job that was
    running, so a job that keeps killing its worker cannot loop forever.
    """
    source = iter(items)
    retry: list[tuple[int, Any]] = []  # jobs a broken pool lost, run first in the next pool
    counter = 0
    while True:
        pending: dict = {}  # future -> (job number, item)
        lost: list[tuple[int, Any]] = []
        with local_pool(workers, env, threads, worker_setup, setup_args, report_starts=True) as (pool, context, started):

            def top_up() -> None:
                nonlocal counter
                while len(pending) < LOCAL_JOBS_PER_WORKER * workers:
                    if retry:
                        number, item = retry.pop(0)
                    else:
                        item = next(source, END)
                        if item is END:
                            return
                        number, counter = counter, counter + 1
                    pending[pool.submit(run_local_job, fn, item, number)] = (number, item)

            top_up()
            while pending:
                done, _ = wait(pending, timeout=POLL_S, return_when=FIRST_COMPLETED)
                for future in done:
                    number, item = pending.pop(future)
                    try:
                        ok, payload, pid = future.result()
                    except BrokenProcessPool:
                        lost.append((number, item))
                        continue
                    except Exception as exc:  # the item, fn or result could not be pickled
                        yield item, JobFailed("error", type(exc).__name__, str(exc))
                        continue
                    if not lost:
                        top_up()
                    yield item, (payload if ok else failure_from_traceback(payload))
                if lost:  # the pool is broken: every pending future fails with it
                    lost += [pending.pop(f) for f in list(pending)]
        if not lost:
            return
        runs: dict[int, int] = {}  # job number -> pid it started on
        while not started.empty():
            pid, number = started.get()
            runs[number] = pid
        started.close()
        codes = {process.pid: process.exitcode for process in context.started}
        ran = [(number, item) for number, item in lost if number in runs]
        blamed = [(n, i) for n, i in ran if codes.get(runs[n]) not in (None, 0, -signal.SIGTERM)] or ran
        if not blamed:  # no job had started: the workers die on their own (a broken interpreter, setup)
            raise job_error(fn, lost[0][1], "the worker processes died before any job started", None)
        for number, item in sorted(blamed, key=lambda pair: pair[0]):
            yield item, killed_failure(codes.get(runs[number]))
        blamed_numbers = {n for n, _ in blamed}
        retry = sorted([pair for pair in lost if pair[0] not in blamed_numbers], key=lambda pair: pair[0]) + retry
