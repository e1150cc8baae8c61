"""Run independent jobs on a local process pool or on a Ray cluster, with single-threaded workers.

One entry point, :func:`map_unordered`, yields ``(item, result)`` pairs as jobs finish, whichever
executor runs them:

- ``"local"``: a :class:`concurrent.futures.ProcessPoolExecutor` of ``workers`` *spawned* processes
  (never forked: a forked child inherits the driver's BLAS/OpenMP thread pools and locks).
- ``"ray"``: ``workers`` Ray actors (``num_cpus=1`` each) on a local Ray instance started for the call
  or on an existing cluster (``address=``).

Why the thread limits: N worker processes on N cores must each run their numerical libraries on
``threads_per_worker`` threads (1 by default), or they oversubscribe the cores, and a BLAS reduction
can sum in a different order with a different thread count, which breaks byte-identical datasets.
OpenBLAS and OpenMP read ``OMP_NUM_THREADS`` and friends once, when the library loads, so the
variables must be in the worker's environment *before* numpy is imported there: the local pool puts
them in the environment each worker process is started with, Ray puts them in the actors'
``runtime_env``. Each worker then also calls ``torch.set_num_threads`` (if torch is installed) and
``threadpoolctl.threadpool_limits`` (if installed) for libraries that were loaded earlier.

The module imports only the standard library: a spawned worker imports it (to unpickle the
initializer) before the thread limits are applied, so it must not pull numpy in.
"""

from __future__ import annotations

import logging
import multiprocessing.context
import os
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterable, Iterator, Mapping
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from multiprocessing.connection import wait as wait_for_sentinels
from typing import Any

__all__ = ["EXECUTORS", "ON_FAILURE", "THREAD_ENV_VARS", "map_unordered", "thread_limit_env"]

EXECUTORS = ("local", "ray")
#: What :func:`map_unordered` does when a job raises or its worker dies: stop the whole map, or
#: yield a :class:`mlsim.dataset.failures.JobFailed` for that item and go on with the others (issue 39).
ON_FAILURE = ("raise", "record")

THREAD_ENV_VARS = (
    "OMP_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
    "NUMEXPR_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
    # numba's own pool (the render, contact and field kernels): its default, the core count, gave each
    # of N workers N threads, N^2 on N cores. The kernels' sums do not depend on it (tested per kernel)
    "NUMBA_NUM_THREADS",
)

# How many jobs the local pool holds per worker: one running and one queued keeps every worker busy
# while the driver handles a result, without pickling the whole item list into the pool up front.
_LOCAL_JOBS_PER_WORKER = 2
# The driver wakes this often while it waits, so a Ctrl-C is handled even when the signal lands on
# another thread (a blocked lock wait in the main thread is only interrupted by its own signals).
_POLL_S = 0.5
# How long terminated workers get to exit before they are killed.
_JOIN_S = 5.0

_END = object()


def thread_limit_env(threads_per_worker: int) -> dict[str, str]:
    """Environment variables that cap the numerical libraries of a worker at some number of threads.

    Parameters
    ----------
    threads_per_worker : int
        Threads each of OpenMP, OpenBLAS, MKL, numexpr and Accelerate (vecLib) may use, >= 1.

    Returns
    -------
    dict of str to str
        One entry per name in :data:`THREAD_ENV_VARS`, each ``str(threads_per_worker)``.

    Raises
    ------
    ValueError
        If ``threads_per_worker`` is not an integer >= 1.
    """
    _check_positive_int("threads_per_worker", threads_per_worker)
    return {name: str(threads_per_worker) for name in THREAD_ENV_VARS}


def map_unordered(
    fn: Callable[[Any], Any],
    items: Iterable[Any],
    *,
    executor: str = "local",
    workers: int = 1,
    address: str | None = None,
    worker_setup: Callable[..., Any] | None = None,
    setup_args: tuple = (),
    threads_per_worker: int = 1,
    on_failure: str = "raise",
) -> Iterator[tuple[Any, Any]]:
    """Run ``fn(item)`` for every item on a pool of worker processes; yield pairs as jobs finish.

    The jobs must be independent. Results come back in completion order, each paired with the item
    (the driver's own object, not a copy) that produced it. Items are drawn from ``items`` lazily, a
    few per worker at a time, so a generator of many items is fine.

    Parameters
    ----------
    fn : callable
        A module-level function of one item (workers import it by module path), returning a small
        picklable result.
    items : iterable
        Small picklable objects, e.g. dicts; a dict's ``"episode_id"`` names it in error messages.
    executor : {"local", "ray"}
        ``"local"``: a spawn-context process pool of ``workers`` processes on this machine; used for
        ``workers=1`` too (not run in-process), so the thread limits and results match any other
        worker count. ``"ray"``: ``workers`` Ray actors, each with ``num_cpus=1``.
    workers : int
        Number of worker processes (local) or actors (Ray), >= 1. On a cluster with fewer free CPUs
        the extra actors wait for resources and the others do the work.
    address : str, optional
        Ray only: the cluster to connect to, e.g. ``"127.0.0.1:6379"`` or ``"ray://head:10001"``.
        ``None`` starts a local Ray instance with ``num_cpus=workers`` for this call and stops it at
        the end (``RAY_ADDRESS`` is not consulted). If this process is already connected to Ray
        (``ray.init`` was called), that connection is used and left open, and ``address`` must be
        ``None``.
    worker_setup : callable, optional
        A module-level function called as ``worker_setup(*setup_args)`` once in each worker process
        before its first job, e.g. to load large precomputed data into a module-level memo.
    setup_args : tuple
        Picklable arguments of ``worker_setup``, sent once per worker (Ray: stored once in the
        object store).
    threads_per_worker : int
        Threads each worker's numerical libraries may use (OpenMP, BLAS, torch), >= 1.
    on_failure : {"raise", "record"}
        ``"raise"``: a failed job stops the map (below). ``"record"``: it is yielded as
        ``(item, mlsim.dataset.failures.JobFailed(...))`` and the others go on. A local worker killed mid-job (a signal,
        the out-of-memory killer) breaks the whole process pool: the job that ran in the dead worker
        is yielded as ``kind="killed"`` with the signal, and the jobs the pool lost with it (running
        in the workers the pool then terminated, or queued) are run again in a new pool. A Ray
        actor that dies is replaced.

    Yields
    ------
    tuple
        ``(item, result)`` with ``result = fn(item)``.

    Raises
    ------
    ValueError
        For an unknown ``executor``, ``workers`` or ``threads_per_worker`` < 1, or an ``address`` with
        ``executor="local"``. Raised by this call, before any iteration.
    TypeError
        If ``fn`` or ``worker_setup`` is not callable, or ``setup_args`` is not a tuple.
    ImportError
        If ``executor="ray"`` and Ray is not installed.
    RuntimeError
        When a job raises (or its worker dies, or ``worker_setup`` failed there): the message names
        the item and holds the worker's traceback. The remaining jobs are cancelled and the workers
        stopped before it is raised.

    Notes
    -----
    Whenever iteration ends early (a job failed, a ``KeyboardInterrupt`` arrived in the driver, the
    consumer broke out of the loop and the generator was closed), the workers are stopped: local
    processes are terminated and joined, Ray actors are killed, and a Ray instance this call started
    is shut down. Local workers ignore SIGINT, so a Ctrl-C reaches only the driver, which stops them.

    Ray workers import ``fn``, ``worker_setup`` and this module by module path, so mlsim (and the
    modules of ``fn``) must be installed on every node of a cluster. A cluster with token
    authentication needs ``RAY_AUTH_MODE=token`` and its token (``RAY_AUTH_TOKEN`` or
    ``~/.ray/auth_token``) in the driver's environment, as for ``ray.init``; a local instance
    started here turns token authentication on by Ray's defaults (Ray 2.60 writes
    ``~/.ray/auth_token`` if there is none and sets ``RAY_AUTH_MODE=token`` in this process).
    """
    if not callable(fn):
        raise TypeError(f"fn = {fn!r}: must be a callable (a module-level function of one item)")
    if executor not in EXECUTORS:
        raise ValueError(f'executor = {executor!r} is not an executor; choose one of: {", ".join(EXECUTORS)}')
    _check_positive_int("workers", workers)
    if on_failure not in ON_FAILURE:
        raise ValueError(f'on_failure = {on_failure!r}: choose one of: {", ".join(ON_FAILURE)}')
    env = thread_limit_env(threads_per_worker)
    if worker_setup is not None and not callable(worker_setup):
        raise TypeError(f"worker_setup = {worker_setup!r}: must be a callable or None")
    if not isinstance(setup_args, tuple):
        raise TypeError(f"setup_args = {setup_args!r}: must be a tuple, e.g. (path,) for one argument")
    if executor == "local":
        if address is not None:
            raise ValueError(
                f'address = {address!r} is only for executor="ray": drop it, or pass executor="ray"'
            )
        if on_failure == "record":
            from mlsim.dataset.failures import map_local_recording

            return map_local_recording(fn, items, workers, env, threads_per_worker, worker_setup, setup_args)
        return _map_local(fn, items, workers, env, threads_per_worker, worker_setup, setup_args)
    ray = _import_ray()
    if address is not None and ray.is_initialized():
        raise ValueError(
            f"address = {address!r}: this process is already connected to Ray; pass address=None to "
            "use that connection, or call ray.shutdown() first"
        )
    return _map_ray(ray, fn, items, workers, address, env, threads_per_worker, worker_setup, setup_args, on_failure == "record")


def _check_positive_int(name: str, value) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"{name} = {value!r}: must be an integer >= 1")


def _item_label(item) -> str:
    """How an error message names an item: its episode_id if it is a dict with one, else its repr."""
    if isinstance(item, Mapping) and "episode_id" in item:
        return f"episode_id={item['episode_id']!r}"
    text = repr(item)
    return text if len(text) <= 200 else text[:197] + "..."


def _callable_name(fn) -> str:
    return f"{getattr(fn, '__module__', '?')}.{getattr(fn, '__qualname__', repr(fn))}"


def _last_line(text: str) -> str:
    """The last non-blank line of a traceback: the exception's type and message."""
    lines = [line for line in text.splitlines() if line.strip()]
    return lines[-1].strip() if lines else ""


def _job_error(fn, item, detail: str, remote_traceback: str | None) -> RuntimeError:
    message = f"job {_callable_name(fn)} failed for item {_item_label(item)}: {detail}"
    if remote_traceback:
        message += f"\n\nWorker traceback:\n{remote_traceback.rstrip()}"
    return RuntimeError(message)


# --- in the worker ------------------------------------------------------------------------------


def _prepare_worker(env: dict[str, str], threads: int, worker_setup, setup_args) -> str | None:
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


def _run_job(fn, item, setup_error: str | None) -> tuple[bool, Any, int]:
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


class _ThreadLimitedSpawnContext(multiprocessing.context.SpawnContext):
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
    _LOCAL_WORKER["started"] = started  # a SimpleQueue of (pid, job number) when the driver records failures
    # Ctrl-C in a terminal reaches the whole process group: the driver alone handles it (it stops
    # the workers), instead of every worker printing a KeyboardInterrupt traceback.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _LOCAL_WORKER["setup_error"] = _prepare_worker(env, threads, worker_setup, setup_args)


def _run_local_job(fn, item, number: int | None = None):
    if number is not None and _LOCAL_WORKER["started"] is not None:
        # SimpleQueue.put writes to the pipe before it returns (mp.Queue's feeder thread may not,
        # before a SIGKILL): the driver learns which job a worker that dies was running
        _LOCAL_WORKER["started"].put((os.getpid(), number))
    return _run_job(fn, item, _LOCAL_WORKER["setup_error"])


def _map_local(fn, items, workers, env, threads, worker_setup, setup_args) -> Iterator[tuple[Any, Any]]:
    # A generator inside a plain function: map_unordered validates when called, not when iterated.
    context = _ThreadLimitedSpawnContext(env)
    pool = ProcessPoolExecutor(
        max_workers=workers,
        mp_context=context,
        initializer=_init_local_worker,
        initargs=(env, threads, worker_setup, setup_args),
    )
    source = iter(items)
    pending = {}  # future -> item

    def top_up() -> None:
        while len(pending) < _LOCAL_JOBS_PER_WORKER * workers:
            item = next(source, _END)
            if item is _END:
                return
            pending[pool.submit(_run_local_job, fn, item)] = item

    finished = False
    try:
        top_up()
        while pending:
            done, _ = wait(pending, timeout=_POLL_S, return_when=FIRST_COMPLETED)
            for future in done:
                item = pending.pop(future)
                result = _local_result(fn, item, future)
                top_up()
                yield item, result
        finished = True
    finally:
        if finished:
            pool.shutdown(wait=True)
        else:
            _stop_local(pool, context)


def _local_result(fn, item, future):
    try:
        ok, payload, pid = future.result()
    except Exception as exc:
        # The job never ran to completion in a live worker: the worker died (BrokenProcessPool), or
        # the item, fn or result could not be pickled.
        cause = exc.__cause__  # the pool's _RemoteTraceback, when there is one
        raise _job_error(fn, item, f"{type(exc).__name__}: {exc}", str(cause) if cause else None) from exc
    if not ok:
        raise _job_error(fn, item, f"{_last_line(payload)} (worker pid {pid})", payload)
    return payload


def _stop_local(pool: ProcessPoolExecutor, context: _ThreadLimitedSpawnContext) -> None:
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


# --- Ray ----------------------------------------------------------------------------------------


def _import_ray():
    try:
        import ray
    except ImportError as exc:
        raise ImportError(
            'executor="ray" needs Ray, which is not installed: install it with pip install "mlsim[ray]" '
            "(or pip install ray)"
        ) from exc
    return ray


class _RayWorker:
    """The body of a Ray actor: set up once, then run jobs one at a time."""

    def __init__(self, fn, env, threads, worker_setup, setup_args):
        self._fn = fn
        self._setup_error = _prepare_worker(env, threads, worker_setup, setup_args)

    def run(self, item):
        return _run_job(self._fn, item, self._setup_error)


def _map_ray(ray, fn, items, workers, address, env, threads, worker_setup, setup_args, record=False):
    from mlsim.dataset.failures import JobFailed, failure_from_traceback
    connected_here = not ray.is_initialized()
    if connected_here:
        if address is None:
            # "local": start a new instance even if `ray start` left a cluster on this machine.
            ray.init(
                address="local", num_cpus=workers, include_dashboard=False, logging_level=logging.WARNING
            )
        else:
            ray.init(address=address, logging_level=logging.WARNING)
    actors = []
    finished = False
    try:
        actor_class = ray.remote(_RayWorker).options(
            num_cpus=1, max_restarts=0, runtime_env={"env_vars": dict(env)}
        )
        setup_ref = ray.put(setup_args)  # one copy in the object store, however many actors
        actors = [actor_class.remote(fn, env, threads, worker_setup, setup_ref) for _ in range(workers)]
        source = iter(items)
        pending = {}  # object ref -> (actor, item)

        def submit(actor) -> None:
            item = next(source, _END)
            if item is not _END:
                pending[actor.run.remote(item)] = (actor, item)

        for actor in actors:
            submit(actor)
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=_POLL_S)
            for ref in ready:
                actor, item = pending.pop(ref)
                try:
                    ok, payload, pid = ray.get(ref)
                except ray.exceptions.RayError as exc:
                    # The actor died (killed, out of memory, crashed) or the result was lost.
                    if not record:
                        raise _job_error(fn, item, f"{type(exc).__name__} on Ray", str(exc)) from exc
                    try:
                        ray.kill(actor)
                    except Exception:  # already dead
                        pass
                    actors.remove(actor)
                    actor = actor_class.remote(fn, env, threads, worker_setup, setup_ref)  # a replacement
                    actors.append(actor)
                    submit(actor)
                    yield item, JobFailed("killed", type(exc).__name__, f"its Ray actor died: {_last_line(str(exc))}")
                    continue
                if not ok and not record:
                    raise _job_error(fn, item, f"{_last_line(payload)} (Ray worker pid {pid})", payload)
                submit(actor)
                yield item, (payload if ok else failure_from_traceback(payload))
        finished = True
    finally:
        if not finished:
            for actor in actors:
                try:
                    ray.kill(actor)
                except Exception:  # already dead, or the connection is gone: nothing left to stop
                    pass
        # Without handles the actors exit (gracefully, when all went well).
        actors = None
        if connected_here:
            # Stops the instance this call started; on a cluster, only disconnects this driver.
            ray.shutdown()


# --- self-test jobs (module level: spawned and Ray workers import them by module path) -----------

_SELFTEST_MEMO: dict[str, Any] = {}


def _selftest_setup(tag: str) -> None:
    """A worker_setup for tests: counts its calls in this process's memo."""
    _SELFTEST_MEMO["setup_calls"] = _SELFTEST_MEMO.get("setup_calls", 0) + 1
    _SELFTEST_MEMO["tag"] = tag
    _SELFTEST_MEMO["jobs_run"] = 0


def _selftest_job(item: Mapping) -> dict:
    """A job for tests: squares ``item["x"]`` and reports what the worker process looks like."""
    import numpy as np

    _SELFTEST_MEMO["jobs_run"] = _SELFTEST_MEMO.get("jobs_run", 0) + 1
    time.sleep(item.get("sleep_s", 0.0))
    if item.get("fail"):
        raise ValueError(f"selftest failure requested by episode {item.get('episode_id')}")
    if item.get("die"):
        os._exit(3)  # a worker that crashes (segfault, out of memory) rather than raising
    torch = sys.modules.get("torch")  # imported by the worker's thread set-up, if installed
    return {
        "square": int(np.square(item["x"])),
        "pid": os.getpid(),
        "setup_calls": _SELFTEST_MEMO.get("setup_calls", 0),
        "tag": _SELFTEST_MEMO.get("tag"),
        "jobs_run": _SELFTEST_MEMO["jobs_run"],
        "env": {name: os.environ.get(name) for name in THREAD_ENV_VARS},
        "blas_threads": _blas_threads(),
        "torch_threads": torch.get_num_threads() if torch is not None else None,
    }


def _blas_threads() -> int | None:
    """Threads of the BLAS numpy uses in this process (threadpoolctl, else OpenBLAS via ctypes)."""
    try:
        from threadpoolctl import threadpool_info
    except ImportError:
        pass
    else:
        counts = [info["num_threads"] for info in threadpool_info() if info.get("user_api") == "blas"]
        return max(counts) if counts else None
    import ctypes

    try:
        with open("/proc/self/maps") as maps:  # Linux: the shared libraries loaded in this process
            paths = {line.split()[-1] for line in maps if "openblas" in line.lower()}
    except OSError:
        return None
    for path in sorted(paths):
        library = ctypes.CDLL(path)
        for symbol in (
            "scipy_openblas_get_num_threads64_",
            "scipy_openblas_get_num_threads",
            "openblas_get_num_threads64_",
            "openblas_get_num_threads",
        ):
            getter = getattr(library, symbol, None)
            if getter is not None:
                return int(getter())
    return None
