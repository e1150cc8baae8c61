"""The worker side of :func:`mlsim.dataset.executors.map_unordered`: what runs inside a worker process
(thread limits, ``worker_setup``, one job), the local process pool whose spawned workers have the
thread limits in their environment from their start (:func:`local_pool`, which also stops them), and
the error that names a failed job.

Its own module so that the two drivers of the local pool, :mod:`mlsim.dataset.executors` (a failure
stops the map) and :mod:`mlsim.dataset.failures` (failures recorded, a broken pool replaced, issue
39), both import it and neither imports the other's internals: before, failures imported these
helpers from executors, which imports failures, an import circle (tests/test_layers.py).

Standard library only: a spawned worker imports this module (to unpickle the initializer and the
job runner) before the thread limits are applied, so it must not pull numpy in.
"""

from __future__ import annotations

import multiprocessing.context
import os
import signal
import threading
import time
import traceback
from collections.abc import Mapping
from contextlib import contextmanager
from concurrent.futures import ProcessPoolExecutor
from multiprocessing.connection import wait as wait_for_sentinels
from typing import Any

__all__ = ["END", "LOCAL_JOBS_PER_WORKER", "POLL_S", "ThreadLimitedSpawnContext", "job_error", "last_line", "local_pool", "prepare_worker",
           "run_job", "run_local_job"]

# How many jobs the local pool holds per worker: one running and one queued keeps every worker busy
# while the driver handles a result, without pickling the whole item list into the pool up front.
LOCAL_JOBS_PER_WORKER = 2
# The driver wakes this often while it waits, so a Ctrl-C is handled even when the signal lands on
# another thread (a blocked lock wait in the main thread is only interrupted by its own signals).
POLL_S = 0.5
# How long terminated workers get to exit before they are killed.
_JOIN_S = 5.0

# Marks an exhausted item iterator (None or any other value could be an item).
END = object()


def _item_label(item) -> str:
    """How an error message names an item: its episode_id if it is a dict with one, else its repr."""
    if isinstance(item, Mapping) and "episode_id" in item:
        return f"episode_id={item['episode_id']!r}"
    text = repr(item)
    return text if len(text) <= 200 else text[:197] + "..."


def _callable_name(fn) -> str:
    return f"{getattr(fn, '__module__', '?')}.{getattr(fn, '__qualname__', repr(fn))}"


def last_line(text: str) -> str:
    """The last non-blank line of a traceback: the exception's type and message."""
    lines = [line for line in text.splitlines() if line.strip()]
    return lines[-1].strip() if lines else ""


def job_error(fn, item, detail: str, remote_traceback: str | None) -> RuntimeError:
    """The error a failed job raises in the driver: names the job and the item, holds the worker's traceback."""
    message = f"job {_callable_name(fn)} failed for item {_item_label(item)}: {detail}"
    if remote_traceback:
        message += f"\n\nWorker traceback:\n{remote_traceback.rstrip()}"
    return RuntimeError(message)


# --- in the worker ------------------------------------------------------------------------------


def prepare_worker(env: dict[str, str], threads: int, worker_setup, setup_args) -> str | None:
    """Apply the thread limits, then run ``worker_setup``; return its traceback text if it raised.

    A failed setup is reported by the worker's first job, not raised here: a raising pool
    initializer breaks the whole pool with an error that names neither the cause nor an item.
    """
    # Already in the environment the process started with; this covers a worker that was not
    # started by us (and libraries, like numexpr, that read the variables at first use).
    os.environ.update(env)
    _limit_loaded_libraries(threads)
    if worker_setup is None:
        return None
    try:
        worker_setup(*setup_args)
    except Exception:
        where = f"worker_setup {_callable_name(worker_setup)} raised in worker pid {os.getpid()}"
        return f"{where}:\n{traceback.format_exc()}"
    return None


def _limit_loaded_libraries(threads: int) -> None:
    """Cap the thread pools of torch and of BLAS/OpenMP libraries that are already loaded."""
    try:
        import torch
    except ImportError:
        pass
    else:
        torch.set_num_threads(threads)
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        return
    # Process-wide and permanent: the returned object only matters to restore the old limits.
    threadpool_limits(limits=threads)


def run_job(fn, item, setup_error: str | None) -> tuple[bool, Any, int]:
    """``(True, fn(item), pid)``, or ``(False, traceback text, pid)`` if the job or setup raised."""
    if setup_error is not None:
        return False, setup_error, os.getpid()
    try:
        return True, fn(item), os.getpid()
    except Exception:
        return False, traceback.format_exc(), os.getpid()


# --- local process pool ------------------------------------------------------------------------

# Per worker process: what _init_local_worker found (the pool has no other place to keep it).
_LOCAL_WORKER: dict[str, Any] = {"setup_error": None, "started": None}
# os.environ is shared by every thread of the driver: one worker start at a time edits it.
_ENVIRON_LOCK = threading.Lock()


class _ThreadLimitedSpawnProcess(multiprocessing.context.SpawnProcess):
    """A spawned process whose environment holds ``start_env`` from its first instruction on.

    The environment of a spawned child is the parent's ``os.environ`` at the moment it is exec'd, and
    the child imports the driver's ``__main__`` module (which may import numpy) before any
    initializer runs: so the variables go into ``os.environ`` around ``start()`` and out again.
    """

    start_env: dict[str, str] = {}

    def start(self):
        with _ENVIRON_LOCK:
            saved = {name: os.environ.get(name) for name in self.start_env}
            os.environ.update(self.start_env)
            try:
                super().start()
            finally:
                for name, value in saved.items():
                    if value is None:
                        os.environ.pop(name, None)
                    else:
                        os.environ[name] = value


class ThreadLimitedSpawnContext(multiprocessing.context.SpawnContext):
    """The spawn context, with processes started under ``env``; remembers them to stop them."""

    def __init__(self, env: dict[str, str]):
        self._env = dict(env)
        self.started: list[_ThreadLimitedSpawnProcess] = []

    def Process(self, *args, **kwargs):  # noqa: N802 (the multiprocessing context API)
        process = _ThreadLimitedSpawnProcess(*args, **kwargs)
        process.start_env = self._env
        self.started.append(process)
        return process


def _init_local_worker(env, threads, worker_setup, setup_args, started=None) -> None:
    """The local pool's initializer: ignore SIGINT, apply the thread limits, run ``worker_setup`` once.

    ``started``, when given, is a :class:`multiprocessing.SimpleQueue` on which :func:`run_local_job`
    reports each job it starts (:func:`mlsim.dataset.failures.map_local_recording` reads it).
    """
    _LOCAL_WORKER["started"] = started  # a SimpleQueue of (pid, job number) when the driver records failures
    # Ctrl-C in a terminal reaches the whole process group: the driver alone handles it (it stops
    # the workers), instead of every worker printing a KeyboardInterrupt traceback.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _LOCAL_WORKER["setup_error"] = prepare_worker(env, threads, worker_setup, setup_args)


def run_local_job(fn, item, number: int | None = None) -> tuple[bool, Any, int]:
    """Run one job in a local worker (:func:`run_job`), first reporting ``(pid, number)`` when asked."""
    if number is not None and _LOCAL_WORKER["started"] is not None:
        # SimpleQueue.put writes to the pipe before it returns (mp.Queue's feeder thread may not,
        # before a SIGKILL): the driver learns which job a worker that dies was running
        _LOCAL_WORKER["started"].put((os.getpid(), number))
    return run_job(fn, item, _LOCAL_WORKER["setup_error"])


@contextmanager
def local_pool(workers: int, env: dict[str, str], threads: int, worker_setup, setup_args, report_starts: bool = False):
    """A spawn-context process pool of thread-limited workers, stopped whichever way the block ends.

    Yields ``(pool, context, started)``: the :class:`~concurrent.futures.ProcessPoolExecutor`, its
    :class:`ThreadLimitedSpawnContext` (``context.started``: the processes, with their exit codes
    once the pool is done) and, with ``report_starts``, the :class:`multiprocessing.SimpleQueue` on
    which each worker puts ``(pid, job number)`` as a job starts (else ``None``). A block that ends
    normally waits for the pool; one left by an exception, or by closing the generator it runs in
    (a consumer that stops iterating), stops the workers at once (``_stop_local``).
    """
    context = ThreadLimitedSpawnContext(env)
    started = context.SimpleQueue() if report_starts else None
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=context, initializer=_init_local_worker,
                               initargs=(env, threads, worker_setup, setup_args, started))
    finished = False
    try:
        yield pool, context, started
        finished = True
    finally:
        if finished:
            pool.shutdown(wait=True)
        else:
            _stop_local(pool, context)


def _stop_local(pool: ProcessPoolExecutor, context: ThreadLimitedSpawnContext) -> None:
    """Cancel the queued jobs and terminate the workers now, instead of waiting for running jobs.

    Terminate first, then shut down: the pool's manager thread sees its workers die, fails the
    queued futures and reaps the processes, and ``shutdown(wait=True)`` waits for that thread. (A
    ``shutdown(wait=False)`` first would drop the pool's reference to the thread, and reaping from
    two threads races: one of them sees a running process that is already gone.) Only processes
    that have not exited are signalled, so no signal can reach a reaped, reused pid.
    """
    running = _still_running([process for process in context.started if process.pid is not None], 0.0)
    for process in running:
        process.terminate()
    for process in _still_running(running, _JOIN_S):  # SIGTERM handled or ignored by a job
        process.kill()
    pool.shutdown(wait=True, cancel_futures=True)


def _still_running(processes: list, timeout_s: float) -> list:
    """The processes that have not exited after waiting up to timeout_s for all of them (no reaping)."""
    deadline = time.monotonic() + timeout_s
    running = list(processes)
    while running:
        left_s = max(0.0, deadline - time.monotonic())
        exited = set(wait_for_sentinels([process.sentinel for process in running], left_s))
        if not exited:
            break
        running = [process for process in running if process.sentinel not in exited]
    return running
