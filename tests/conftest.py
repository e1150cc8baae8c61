"""Shared fixtures: a private cache for the whole session, and meshes built once per session."""

from __future__ import annotations

import importlib.util
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def pytest_configure(config):
    # pytest-xdist's workers (make test: -n 2) share the cache their controller made and seeded: a
    # precompute one worker made (a transport matrix, the reduced tier's) is the other's too
    if os.environ.get("PYTEST_XDIST_WORKER") and os.environ.get("MLSIM_CACHE_DIR"):
        return
    # Never touch the user's cache from tests; runs inside the session share this one.
    if "MLSIM_CACHE_DIR" not in os.environ or not os.environ.get("MLSIM_TEST_KEEP_CACHE"):
        import tempfile

        os.environ["MLSIM_CACHE_DIR"] = tempfile.mkdtemp(prefix="mlsim_test_cache_")
        config._mlsim_made_cache = os.environ["MLSIM_CACHE_DIR"]
    # fTetWild gives a different mesh on every build: the suite uses the shipped ones (tests/data/ship_meshes.py)
    import runpy

    runpy.run_path(str(ROOT / "tests" / "data" / "ship_meshes.py"))["seed_cache"](Path(os.environ["MLSIM_CACHE_DIR"]))
    if config.getoption("warm_kernels"):
        config._mlsim_warmed = _warm_kernels()


def pytest_addoption(parser):
    parser.addoption("--warm-kernels", action="store_true", default=False,
                     help="compile the numba kernels once, a process per group at once, before the workers start "
                          "(tests/warm_kernels.py; make test passes it)")


def _warm_kernels():
    """tests/warm_kernels.py's groups, each in its own process, all at once, on the session's cache: each xdist
    worker would otherwise compile what the other had not cached yet. A group that fails only warns: the tests
    that use its kernels will say what is wrong."""
    import runpy
    import warnings

    script = ROOT / "tests" / "warm_kernels.py"
    groups = runpy.run_path(str(script))["GROUPS"]
    start = time.perf_counter()
    logs = {g: open(Path(os.environ["MLSIM_CACHE_DIR"]) / f"warm_{g}.log", "w+") for g in groups}  # a pipe could fill
    procs = {g: subprocess.Popen([sys.executable, str(script), g], cwd=ROOT, stdout=logs[g], stderr=subprocess.STDOUT)
             for g in groups}
    said = []
    for g, proc in procs.items():
        proc.wait()
        logs[g].seek(0)
        lines = logs[g].read().strip().splitlines()
        logs[g].close()
        if proc.returncode != 0:
            warnings.warn(f"warming the {g} kernels failed (exit {proc.returncode}): {lines[-1:]}")
        said.append(lines[-1] if proc.returncode == 0 and lines else f"{g}: failed")
    return f"warmed the kernels in {time.perf_counter() - start:.0f} s ({'; '.join(said)})"


def pytest_report_header(config):
    return getattr(config, "_mlsim_warmed", None)


def pytest_unconfigure(config):
    # the session's private cache goes with the session (they piled up in /tmp: ~0.5 GB each)
    made = getattr(config, "_mlsim_made_cache", None)
    if made:
        import shutil

        shutil.rmtree(made, ignore_errors=True)
        os.environ.pop("MLSIM_CACHE_DIR", None)


@pytest.fixture(scope="session")
def cache():
    from mlsim.pipeline import Cache

    return Cache(os.environ["MLSIM_CACHE_DIR"])


def _mesh_of(scene_file: str, cache):
    from mlsim import pipeline
    from mlsim.scene import load_scene

    scene = load_scene(ROOT / "scenes" / scene_file)
    result = pipeline.run(scene, out_dir=None, cache=cache, outputs=("mesh",), progress=False, log=lambda m: None)
    from fem.geometry import RodArray

    mesh, report = result.results["mesh"]
    return scene, RodArray.from_sensor(scene.sensor), mesh, report


@pytest.fixture(scope="session")
def tiny_mesh(cache):
    """(scene, geometry, mesh, report) of scenes/mavig_tiny.toml (2 x 2 rods, about 5 s)."""
    return _mesh_of("mavig_tiny.toml", cache)


@pytest.fixture(scope="session")
def default_mesh(cache):
    """(scene, geometry, mesh, report) of scenes/mavig_default.toml at default fidelity (about 30 s)."""
    return _mesh_of("mavig_default.toml", cache)


# --- Ray (tests/test_executors.py, tests/test_dataset.py) ---------------------------------------

# Nothing may reach for the network: no usage reports, no uv/conda detection. Token authentication
# with a token of this session only: the GCS listens on every interface whatever --node-ip-address
# says, and a token in the environment keeps Ray from writing one to ~/.ray/auth_token.
RAY_TEST_ENV = {
    "RAY_USAGE_STATS_ENABLED": "0",
    "RAY_ENABLE_UV_RUN_RUNTIME_ENV": "0",
    "RAY_AUTH_MODE": "token",
    "RAY_AUTH_TOKEN": secrets.token_hex(32),
}


@pytest.fixture
def ray_quiet(monkeypatch):
    for name, value in RAY_TEST_ENV.items():
        monkeypatch.setenv(name, value)
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    ray = pytest.importorskip("ray")
    # Ray reads RAY_AUTH_MODE and the token when it loads: re-read them if something imported it
    # earlier in the session (the way ray.init itself does when it turns token mode on).
    from ray._raylet import AuthenticationTokenLoader, Config

    Config.initialize("")
    AuthenticationTokenLoader.instance().reset_cache()
    yield ray
    if ray.is_initialized():  # a failed test must not leave the driver connected
        ray.shutdown()


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _processes_mentioning(text: str) -> list[int]:
    """Pids whose command line contains text (Linux /proc): the processes of one Ray session."""
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and int(entry.name) != os.getpid():
            try:
                if text in (entry / "cmdline").read_bytes().decode(errors="replace"):
                    pids.append(int(entry.name))
            except OSError:
                pass
    return pids


@pytest.fixture(scope="session")
def ray_cluster(tmp_path_factory):
    """A 2-CPU Ray head on loopback, started for the session and stopped (only it) at the end.

    `ray start --block` stays in the foreground and takes the cluster down when it is terminated;
    `ray stop` is not used: it kills every Ray process of the machine, not only this cluster's.
    """
    if importlib.util.find_spec("ray") is None:  # not imported here: see ray_quiet
        pytest.skip("ray is not installed")
    ray_cli = Path(sys.executable).with_name("ray")
    if not ray_cli.exists():
        pytest.skip(f"no ray command next to {sys.executable}")
    port = _free_port()
    # a private, short temp dir (Ray's socket paths must stay under 107 characters) marks our processes
    temp_dir = Path("/tmp") / f"rt{os.getpid()}_{port}"
    env = {**os.environ, **RAY_TEST_ENV}
    env.pop("RAY_ADDRESS", None)
    log = tmp_path_factory.mktemp("ray") / "ray_start.log"
    command = [
        str(ray_cli), "start", "--head", "--block",
        "--node-ip-address=127.0.0.1", f"--port={port}", "--num-cpus=2",
        "--include-dashboard=false", "--disable-usage-stats", f"--temp-dir={temp_dir}",
    ]  # fmt: skip
    with open(log, "wb") as out:
        # its own session: the finalizer can clear up exactly this group of processes
        head = subprocess.Popen(
            command, stdout=out, stderr=subprocess.STDOUT, env=env, start_new_session=True
        )
    try:
        deadline = time.monotonic() + 60
        while True:
            if head.poll() is not None:
                pytest.fail(f"ray start exited with {head.returncode}:\n{log.read_text()}")
            status = subprocess.run(
                [str(ray_cli), "status", f"--address=127.0.0.1:{port}"],
                env=env, capture_output=True, text=True, timeout=30,
            )  # fmt: skip
            if status.returncode == 0 and "2.0 CPU" in status.stdout:
                break
            if time.monotonic() > deadline:
                pytest.fail(f"the Ray head did not come up in 60 s:\n{log.read_text()}\n{status.stdout}")
            time.sleep(0.5)
        yield f"127.0.0.1:{port}"
    finally:
        # The head alone: it drains the node and stops its daemons in ~2 s. Signalling the whole
        # group kills the GCS first, and the head then waits 30 s for it before giving up.
        head.send_signal(signal.SIGTERM)
        try:
            head.wait(timeout=30)
        except subprocess.TimeoutExpired:
            head.kill()
            head.wait()
        try:
            os.killpg(head.pid, signal.SIGKILL)  # whatever is left of the group started above
        except ProcessLookupError:
            pass
        # Ray daemons that left the process group: by pid, and only those of this cluster
        for pid in _processes_mentioning(str(temp_dir)):
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        shutil.rmtree(temp_dir, ignore_errors=True)
