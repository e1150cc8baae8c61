"""mlsim.dataset.executors: one map_unordered over a spawned process pool and over Ray.

The jobs are mlsim.dataset.executors._selftest_job/_selftest_setup: spawned and Ray workers import
a job by module path, and tests/ is not a package (pytest imports this file as a top-level module
whose directory the workers' sys.path need not hold).
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import threading
import time

import pytest

from mlsim.dataset.executors import (
    THREAD_ENV_VARS,
    _selftest_job,
    _selftest_setup,
    map_unordered,
    thread_limit_env,
)

ITEMS = [{"episode_id": i, "x": i, "sleep_s": 0.1} for i in range(20)]


def _check_results(pairs, items, workers, tag):
    """Each item once, the serial results, worker_setup once per worker process, one thread each."""
    assert sorted(item["episode_id"] for item, _ in pairs) == [item["episode_id"] for item in items]
    serial = {(item["episode_id"], _selftest_job({**item, "sleep_s": 0.0})["square"]) for item in items}
    assert {(item["episode_id"], result["square"]) for item, result in pairs} == serial
    # the yielded item is the driver's object, not a copy made by unpickling
    assert all(any(item is original for original in items) for item, _ in pairs)

    results = [result for _, result in pairs]
    pids = {result["pid"] for result in results}
    assert os.getpid() not in pids
    # Ray hands every actor a job before any gets a second; the local pool is that fast here
    assert len(pids) == workers, f"expected {workers} worker processes, saw {len(pids)}"
    assert {result["setup_calls"] for result in results} == {1}
    assert {result["tag"] for result in results} == {tag}
    # the memo that worker_setup filled lives on across the jobs of a process: 1, 2, ..., n each
    for pid in pids:
        counts = sorted(result["jobs_run"] for result in results if result["pid"] == pid)
        assert counts == list(range(1, len(counts) + 1))

    assert all(result["env"] == dict.fromkeys(THREAD_ENV_VARS, "1") for result in results)
    # torch is installed with mlsim: the worker capped it
    assert {result["torch_threads"] for result in results} == {1}
    blas = {result["blas_threads"] for result in results}
    if blas == {None}:
        pytest.skip("cannot read the BLAS thread count here (no threadpoolctl, no OpenBLAS via ctypes)")
    assert blas == {1}


# --- pure parts and argument checks ---------------------------------------------------------


def test_thread_limit_env():
    assert thread_limit_env(3) == {
        "OMP_NUM_THREADS": "3",
        "OPENBLAS_NUM_THREADS": "3",
        "MKL_NUM_THREADS": "3",
        "NUMEXPR_NUM_THREADS": "3",
        "VECLIB_MAXIMUM_THREADS": "3",
        "NUMBA_NUM_THREADS": "3",
    }
    for bad in (0, -1, 1.0, "1", True):
        with pytest.raises(ValueError, match="threads_per_worker"):
            thread_limit_env(bad)


@pytest.mark.parametrize(
    "kwargs, error, pattern",
    [
        ({"executor": "dask"}, ValueError, "'dask' is not an executor; choose one of: local, ray"),
        ({"workers": 0}, ValueError, "workers = 0: must be an integer >= 1"),
        ({"workers": 2.0}, ValueError, "workers = 2.0"),
        ({"threads_per_worker": 0}, ValueError, "threads_per_worker = 0"),
        ({"address": "127.0.0.1:6379"}, ValueError, 'only for executor="ray"'),
        ({"worker_setup": "setup"}, TypeError, "worker_setup = 'setup'"),
        ({"setup_args": [1]}, TypeError, r"setup_args = \[1\]: must be a tuple"),
    ],
)
def test_bad_arguments_raise_at_call_time(kwargs, error, pattern):
    # raised by the call itself, not at the first next(): no pool is ever started
    with pytest.raises(error, match=pattern):
        map_unordered(_selftest_job, ITEMS, **kwargs)


def test_fn_must_be_callable():
    with pytest.raises(TypeError, match="fn = 3"):
        map_unordered(3, ITEMS)


# --- local process pool ----------------------------------------------------------------------


def test_local_pool_matches_serial_map():
    pairs = list(
        map_unordered(
            _selftest_job,
            ITEMS,
            executor="local",
            workers=2,
            worker_setup=_selftest_setup,
            setup_args=("local",),
        )
    )
    _check_results(pairs, ITEMS, workers=2, tag="local")
    assert multiprocessing.active_children() == []  # the pool is gone


def test_local_pool_honours_threads_per_worker():
    items = [{"episode_id": 0, "x": 3}]
    driver_env = {name: os.environ.get(name) for name in THREAD_ENV_VARS}
    ((_, result),) = map_unordered(_selftest_job, items, workers=1, threads_per_worker=2)
    assert result["square"] == 9
    assert result["pid"] != os.getpid()  # workers=1 is a pool of one process too, not in-process
    assert result["env"] == dict.fromkeys(THREAD_ENV_VARS, "2")
    assert result["torch_threads"] == 2
    # the variables were in os.environ only while the worker started
    assert {name: os.environ.get(name) for name in THREAD_ENV_VARS} == driver_env
    if result["blas_threads"] is not None:
        assert result["blas_threads"] == min(2, os.cpu_count())


def test_local_job_error_names_the_item_and_stops_the_pool():
    items = [{"episode_id": i, "x": i, "sleep_s": 0.05} for i in range(6)]
    items.insert(2, {"episode_id": "ep-bad", "x": 0, "fail": True})
    items += [{"episode_id": 100 + i, "x": i, "sleep_s": 30.0} for i in range(4)]
    started = time.monotonic()
    with pytest.raises(RuntimeError) as info:
        for _ in map_unordered(_selftest_job, items, workers=2):
            pass
    message = str(info.value)
    headline = message.splitlines()[0]
    assert "item episode_id='ep-bad': ValueError: selftest failure requested by episode ep-bad" in headline
    assert "Worker traceback:" in message and "_selftest_job" in message
    # the 30 s jobs were cancelled or terminated, not waited for
    assert time.monotonic() - started < 20
    assert multiprocessing.active_children() == []


def test_local_setup_error_is_reported_with_the_item():
    items = [{"episode_id": 7, "x": 1}]
    pattern = r"(?s)episode_id=7: TypeError: .*_selftest_setup\(\) takes 1 positional.*worker_setup .*raised"
    with pytest.raises(RuntimeError, match=pattern):
        list(map_unordered(_selftest_job, items, worker_setup=_selftest_setup, setup_args=(1, 2)))


def test_local_worker_death_names_the_item():
    items = [{"episode_id": i, "x": i} for i in range(3)] + [{"episode_id": "ep-dies", "x": 0, "die": True}]
    with pytest.raises(RuntimeError, match=r"failed for item episode_id='ep-dies': BrokenProcessPool"):
        for _ in map_unordered(_selftest_job, items, workers=1):
            pass
    assert multiprocessing.active_children() == []


def test_closing_the_generator_early_stops_the_workers():
    items = [{"episode_id": 0, "x": 1}] + [{"episode_id": i, "x": i, "sleep_s": 30.0} for i in range(1, 5)]
    results = map_unordered(_selftest_job, items, workers=2)
    next(results)
    pids = [process.pid for process in multiprocessing.active_children()]
    assert len(pids) == 2
    results.close()
    assert multiprocessing.active_children() == []
    for pid in pids:
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)


@pytest.fixture
def default_sigint():
    """Python's own SIGINT handler for the test (an earlier test's library may have replaced it:
    seen once in a full clean-checkout run), restored afterwards."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def test_keyboard_interrupt_stops_the_workers_and_propagates(default_sigint):
    items = [{"episode_id": 0, "x": 1}] + [{"episode_id": i, "x": i, "sleep_s": 30.0} for i in range(1, 5)]
    main = threading.main_thread().ident
    pids = []
    interrupter = threading.Timer(1.0, signal.pthread_kill, args=(main, signal.SIGINT))
    started = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        for _ in map_unordered(_selftest_job, items, workers=2):
            if not pids:
                pids = [process.pid for process in multiprocessing.active_children()]
                interrupter.start()  # lands while the driver waits on the 30 s jobs
    interrupter.join()
    assert time.monotonic() - started < 20
    assert len(pids) == 2
    assert multiprocessing.active_children() == []
    for pid in pids:
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)


# --- Ray ---------------------------------------------------------------------------------------

# The Ray fixtures (ray_quiet, ray_cluster: a 2-CPU head on loopback for the session) are in conftest.py.


def test_ray_cluster_matches_serial_map(ray_cluster, ray_quiet):
    pairs = list(
        map_unordered(
            _selftest_job,
            ITEMS,
            executor="ray",
            workers=2,
            address=ray_cluster,
            worker_setup=_selftest_setup,
            setup_args=("ray-cluster",),
        )
    )
    _check_results(pairs, ITEMS, workers=2, tag="ray-cluster")
    assert not ray_quiet.is_initialized()  # disconnected again


def test_ray_job_error_names_the_item_and_kills_the_actors(ray_cluster, ray_quiet):
    ray = ray_quiet
    # one actor is 30 s into a job when the other one fails
    items = [
        {"episode_id": 1, "x": 1, "sleep_s": 30.0},
        {"episode_id": "ep-bad", "x": 0, "sleep_s": 1.0, "fail": True},
    ]
    items += [{"episode_id": 100 + i, "x": i} for i in range(3)]
    started = time.monotonic()
    with pytest.raises(RuntimeError) as info:
        for _ in map_unordered(_selftest_job, items, executor="ray", workers=2, address=ray_cluster):
            pass
    assert time.monotonic() - started < 20
    message = str(info.value)
    headline = message.splitlines()[0]
    assert "item episode_id='ep-bad': ValueError: selftest failure requested by episode ep-bad" in headline
    assert "Worker traceback:" in message and "_selftest_job" in message
    assert not ray.is_initialized()
    _assert_cluster_cpus_free(ray, ray_cluster)


def _assert_cluster_cpus_free(ray, address):
    """The killed actors gave their CPUs back to the cluster (a running actor holds one)."""
    ray.init(address=address, logging_level="WARNING")
    try:
        deadline = time.monotonic() + 15
        while ray.available_resources().get("CPU", 0) < 2 and time.monotonic() < deadline:
            time.sleep(0.2)
        assert ray.available_resources().get("CPU", 0) == 2
    finally:
        ray.shutdown()


def test_ray_actor_death_names_the_item(ray_cluster, ray_quiet):
    items = [{"episode_id": 0, "x": 1, "sleep_s": 30.0}, {"episode_id": "ep-dies", "x": 0, "die": True}]
    with pytest.raises(RuntimeError, match=r"failed for item episode_id='ep-dies': \w*ActorDiedError on Ray"):
        for _ in map_unordered(_selftest_job, items, executor="ray", workers=2, address=ray_cluster):
            pass
    _assert_cluster_cpus_free(ray_quiet, ray_cluster)


def test_ray_keyboard_interrupt_kills_the_actors(ray_cluster, ray_quiet, default_sigint):
    ray = ray_quiet
    items = [{"episode_id": 0, "x": 1}] + [{"episode_id": i, "x": i, "sleep_s": 30.0} for i in range(1, 4)]
    main = threading.main_thread().ident
    interrupter = threading.Timer(1.0, signal.pthread_kill, args=(main, signal.SIGINT))
    started = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        for _ in map_unordered(_selftest_job, items, executor="ray", workers=2, address=ray_cluster):
            if not interrupter.is_alive():
                interrupter.start()  # lands while the driver waits on the 30 s jobs
    interrupter.join()
    assert time.monotonic() - started < 20
    assert not ray.is_initialized()
    _assert_cluster_cpus_free(ray, ray_cluster)


def test_ray_without_address_starts_and_stops_a_local_instance(ray_quiet):
    items = ITEMS[:8]
    pairs = list(
        map_unordered(
            _selftest_job,
            items,
            executor="ray",
            workers=2,
            worker_setup=_selftest_setup,
            setup_args=("ray-local",),
        )
    )
    assert not ray_quiet.is_initialized()  # the instance it started is shut down
    _check_results(pairs, items, workers=2, tag="ray-local")
