"""A dataset survives an episode that raises or whose worker is killed (issue 39, item 5): the others
are stored, the failed ones are recorded with their reason (DIR/failures.json, dataset.json, the
card), and a rerun of the same command runs only them, leaving the stored episodes byte-identical.

The failing episodes are made by the job function: the workers are spawned, so a monkeypatched
``run_episode_job`` reaches them only as a module-level function they can import by name (this
module; a spawned child gets the driver's sys.path). One raises (as a solver's refusal does); one
SIGKILLs its own worker process mid-job, as the kernel's out-of-memory killer would.
"""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest

from mlsim.dataset import generate as gen
from mlsim.dataset import store
from mlsim.dataset.executors import _selftest_job, map_unordered
from mlsim.dataset.failures import JobFailed, failure_from_traceback, killed_failure
from mlsim.dataset.spec import load_dataset_spec
from test_dataset import write_spec

RAISES, KILLED = "push_00001", "pull_00000"
_REAL_JOB = gen.run_episode_job


class _Refused(ValueError):
    """Stands for a solver's refusal of one episode's load (a SolverError is a ValueError too)."""


def _job_with_faults(job: dict) -> dict:
    """The real episode job, except RAISES raises and KILLED's worker is killed by SIGKILL."""
    if job["episode_id"] == RAISES:
        raise _Refused(f"episode {RAISES}: the load is refused (made to fail by the test)")
    if job["episode_id"] == KILLED:
        os.kill(os.getpid(), signal.SIGKILL)
    return _REAL_JOB(job)


def _episode_bytes(out: Path) -> dict[str, dict[str, bytes]]:
    """Every stored episode's files, by episode and relative path (the Zarr chunks and metadata)."""
    root = out / store.STORE_NAME / "episodes"
    return {ep.name: {str(f.relative_to(ep)): f.read_bytes() for f in sorted(ep.rglob("*")) if f.is_file()} for ep in sorted(root.iterdir()) if ep.is_dir()}


@pytest.fixture(scope="module")
def faulted(tmp_path_factory, cache):
    """push/pull x 2 episodes generated with RAISES and KILLED failing (2 workers), then the same
    command rerun: (spec, base, out, what the first run gave, what the rerun gave)."""
    tmp = tmp_path_factory.mktemp("faults")
    spec, base = load_dataset_spec(write_spec(tmp, samples_per_action=2, people=2, actions=("push", "pull")))
    out = tmp / "data"
    first: dict = {"lines": []}
    patch = pytest.MonkeyPatch()
    patch.setattr(gen, "run_episode_job", _job_with_faults)
    try:
        first["summary"] = gen.generate(spec, base, out, workers=2, cache_dir=cache.root, progress=False, log=first["lines"].append)
    finally:
        patch.undo()
    first.update(stored=store.complete_episodes(out), failures=store.read_failures(out), card=(out / "README.md").read_text(),
                 partial=sorted(p.name for p in (out / ".partial").glob("*")), bytes=_episode_bytes(out))
    second: dict = {"lines": []}
    second["summary"] = gen.generate(spec, base, out, workers=2, cache_dir=cache.root, progress=False, log=second["lines"].append)
    return spec, base, out, first, second


def test_a_failing_and_a_killed_episode_are_recorded_and_the_others_stored(faulted):
    _, _, out, first, _ = faulted
    summary = first["summary"]
    assert summary["episodes_stored"] == 2 and summary["episodes_failed"] == 2 and not summary["complete"]
    assert first["stored"] == {"push_00000", "pull_00001"} and first["partial"] == []  # nothing half-written
    failures = first["failures"]
    assert failures[RAISES] == {"kind": "error", "error_type": "_Refused", "message": f"episode {RAISES}: the load is refused (made to fail by the test)"}
    assert failures[KILLED]["kind"] == "killed" and failures[KILLED]["error_type"] == "SIGKILL" and "out-of-memory" in failures[KILLED]["message"]
    assert summary["failures"] == failures
    assert any("2 episodes failed" in m and RAISES in m and KILLED in m for m in first["lines"])
    assert "Incomplete: 2 of 4 episodes failed" in first["card"] and "SIGKILL" in first["card"] and "_Refused" in first["card"]


def test_a_rerun_retries_only_the_failed_episodes_and_leaves_the_stored_ones_untouched(faulted):
    _, _, out, first, second = faulted
    rerun = second["summary"]
    assert rerun["episodes_run_now"] == 2 and rerun["complete"] and rerun["episodes_failed"] == 0 and rerun["failures"] == {}
    assert "(2 that failed before)" in second["lines"][0]
    assert any("no driver episode" in m for m in second["lines"])  # the first run listed the sensor's precomputes
    assert not (out / store.FAILURES_NAME).exists() and "Incomplete" not in (out / "README.md").read_text()
    after = _episode_bytes(out)
    assert set(after) == {"push_00000", "push_00001", "pull_00000", "pull_00001"}
    assert {k: after[k] for k in first["bytes"]} == first["bytes"]  # byte for byte, every file


@pytest.mark.slow
def test_the_recovered_dataset_is_the_one_a_run_without_faults_gives(faulted, cache, tmp_path):
    """~30 s more (a third run): behind -m slow."""
    spec, base, out, _, _ = faulted
    clean = tmp_path / "clean"
    gen.generate(spec, base, clean, workers=2, cache_dir=cache.root, progress=False, log=lambda m: None)
    assert store.complete_episodes(clean) == store.complete_episodes(out)
    for ep in sorted(store.complete_episodes(clean)):
        got, want = store.read_episode(out, ep), store.read_episode(clean, ep)
        for name in store.EPISODE_ARRAYS:
            if name in want:
                assert got[name].dtype == want[name].dtype and got[name].tobytes() == want[name].tobytes(), (ep, name)
        timings = ("seconds", "stage_seconds", *store.EPISODE_ARRAYS)
        assert {k: v for k, v in got.items() if k not in timings} == {k: v for k, v in want.items() if k not in timings}


def test_the_executor_records_a_raise_and_a_dead_worker_and_runs_the_rest():
    items = [{"episode_id": f"e{i}", "x": i, "sleep_s": 0.2, "fail": i == 2, "die": i == 4} for i in range(7)]
    results = {item["episode_id"]: r for item, r in map_unordered(_selftest_job, items, workers=2, on_failure="record")}
    assert sorted(results) == [f"e{i}" for i in range(7)]
    for i in (0, 1, 3, 5, 6):  # the jobs the dead worker's pool lost were run again in a new pool
        assert results[f"e{i}"]["square"] == i * i
    assert results["e2"].kind == "error" and results["e2"].error_type == "ValueError" and "requested by episode e2" in results["e2"].message
    assert results["e4"] == JobFailed("killed", "exit 3", "its worker process exited with code 3 before the job finished")
    with pytest.raises(ValueError, match="on_failure = 'skip'"):
        map_unordered(_selftest_job, items, on_failure="skip")


def test_failure_records_name_the_signal_and_the_exception():
    assert killed_failure(-signal.SIGKILL).error_type == "SIGKILL" and "out-of-memory" in killed_failure(-signal.SIGKILL).reason
    assert killed_failure(-signal.SIGSEGV).reason == "killed: its worker process was killed by SIGSEGV"
    failed = failure_from_traceback("Traceback (most recent call last):\n  ...\nfem.errors.SolverError: the press is deeper than the sensor\n")
    assert (failed.kind, failed.error_type, failed.message) == ("error", "SolverError", "the press is deeper than the sensor")
    assert gen.failures_line({"a": {"kind": "killed", "error_type": "SIGKILL", "message": "x"},
                              "b": {"kind": "error", "error_type": "SolverError", "message": "too deep"}}) == \
        "2 episodes failed: a (SIGKILL), b (SolverError: too deep)"


def test_the_command_exits_1_naming_the_failed_episodes(tmp_path, monkeypatch, capsys):
    """``mlsim dataset``: a run that stored every episode but the failed ones exits 1 with the failures'
    line (a dataset with holes is not a success for a script that trains on it); a complete one exits 0."""
    from mlsim import cli

    spec_path = write_spec(tmp_path, samples_per_action=1, people=1, actions=["push", "pull"])
    failed = {"push_00000": {"kind": "error", "error_type": "SolverError", "message": "step 3: no convergence"}}

    outcome = {"failures": failed}

    def fake(spec, base, out, **kw):
        return {"episodes_stored": 1, "episodes_planned": 2, "episodes_run_now": 1, "episodes_wall_s": 1.0, "episodes_per_s": 1.0,
                "precompute_s": 0.0, "episodes_failed": len(outcome["failures"]), "failures": outcome["failures"]}

    monkeypatch.setattr(gen, "generate", fake)
    assert cli.main(["dataset", str(spec_path), "--out", str(tmp_path / "ds"), "--quiet"]) == cli.EXIT_FAILURE
    err = capsys.readouterr().err
    assert "1 episode failed: push_00000 (SolverError: step 3: no convergence)" in err and "retry only them" in err
    outcome["failures"] = {}
    assert cli.main(["dataset", str(spec_path), "--out", str(tmp_path / "ds"), "--quiet"]) == cli.EXIT_OK
