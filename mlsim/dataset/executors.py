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

The worker side (thread limits, the spawn context, running one job, stopping the pool) is in
:mod:`mlsim.dataset.workers`, shared with :mod:`mlsim.dataset.failures` (``on_failure="record"``'s
local pool). All three import only the standard library and each other: a spawned worker imports
them before the thread limits are applied, so they must not pull numpy in.
"""

from __future__ import annotations

import logging
import os
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from concurrent.futures import FIRST_COMPLETED, wait
from typing import Any

from mlsim.dataset.failures import JobFailed, failure_from_traceback, map_local_recording
from mlsim.dataset.workers import END, LOCAL_JOBS_PER_WORKER, POLL_S, job_error, last_line, local_pool, prepare_worker, run_job, run_local_job

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


def _map_local(fn, items, workers, env, threads, worker_setup, setup_args) -> Iterator[tuple[Any, Any]]:
    # A generator inside a plain function: map_unordered validates when called, not when iterated.
    source = iter(items)
    pending = {}  # future -> item
    with local_pool(workers, env, threads, worker_setup, setup_args) as (pool, _, _):

        def top_up() -> None:
            while len(pending) < LOCAL_JOBS_PER_WORKER * workers:
                item = next(source, END)
                if item is END:
                    return
                pending[pool.submit(run_local_job, fn, item)] = item

        top_up()
        while pending:
            done, _ = wait(pending, timeout=POLL_S, return_when=FIRST_COMPLETED)
            for future in done:
                item = pending.pop(future)
                result = _local_result(fn, item, future)
                top_up()
                yield item, result


def _local_result(fn, item, future):
    try:
        ok, payload, pid = future.result()
    except Exception as exc:
        # The job never ran to completion in a live worker: the worker died (BrokenProcessPool), or
        # the item, fn or result could not be pickled.
        cause = exc.__cause__  # the pool's _RemoteTraceback, when there is one
        raise job_error(fn, item, f"{type(exc).__name__}: {exc}", str(cause) if cause else None) from exc
    if not ok:
        raise job_error(fn, item, f"{last_line(payload)} (worker pid {pid})", payload)
    return payload


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
        self._setup_error = prepare_worker(env, threads, worker_setup, setup_args)

    def run(self, item):
        return run_job(self._fn, item, self._setup_error)


def _map_ray(ray, fn, items, workers, address, env, threads, worker_setup, setup_args, record=False):
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
            item = next(source, END)
            if item is not END:
                pending[actor.run.remote(item)] = (actor, item)

        for actor in actors:
            submit(actor)
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=POLL_S)
            for ref in ready:
                actor, item = pending.pop(ref)
                try:
                    ok, payload, pid = ray.get(ref)
                except ray.exceptions.RayError as exc:
                    # The actor died (killed, out of memory, crashed) or the result was lost.
                    if not record:
                        raise job_error(fn, item, f"{type(exc).__name__} on Ray", str(exc)) from exc
                    try:
                        ray.kill(actor)
                    except Exception:  # already dead
                        pass
                    actors.remove(actor)
                    actor = actor_class.remote(fn, env, threads, worker_setup, setup_ref)  # a replacement
                    actors.append(actor)
                    submit(actor)
                    yield item, JobFailed("killed", type(exc).__name__, f"its Ray actor died: {last_line(str(exc))}")
                    continue
                if not ok and not record:
                    raise job_error(fn, item, f"{last_line(payload)} (Ray worker pid {pid})", payload)
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
