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

import numpy as np
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


def test_a_failing_and_a_killed_episode_are_recorded_and_a_rerun_retries_only_them(tmp_path, cache, monkeypatch):
    spec, base = load_dataset_spec(write_spec(tmp_path, samples_per_action=2, people=2, actions=("push", "pull")))
    out, clean = tmp_path / "data", tmp_path / "clean"
    with monkeypatch.context() as patch:
        patch.setattr(gen, "run_episode_job", _job_with_faults)
        lines: list[str] = []
        summary = gen.generate(spec, base, out, workers=2, cache_dir=cache.root, progress=False, log=lines.append)
    assert summary["episodes_stored"] == 2 and summary["episodes_failed"] == 2 and not summary["complete"]
    assert store.complete_episodes(out) == {"push_00000", "pull_00001"}
    failures = store.read_failures(out)
    assert failures[RAISES] == {"kind": "error", "error_type": "_Refused", "message": f"episode {RAISES}: the load is refused (made to fail by the test)"}
    assert failures[KILLED]["kind"] == "killed" and failures[KILLED]["error_type"] == "SIGKILL" and "out-of-memory" in failures[KILLED]["message"]
    assert summary["failures"] == failures
    assert not (out / ".partial").exists() or not any((out / ".partial").iterdir())  # nothing half-written
    assert any("2 episodes failed" in m and RAISES in m and KILLED in m for m in lines)
    card = (out / "README.md").read_text()
    assert "Incomplete: 2 of 4 episodes failed" in card and "SIGKILL" in card and "_Refused" in card
    before = _episode_bytes(out)

    lines = []
    rerun = gen.generate(spec, base, out, workers=2, cache_dir=cache.root, progress=False, log=lines.append)
    assert rerun["episodes_run_now"] == 2 and rerun["complete"] and rerun["episodes_failed"] == 0
    assert "(2 that failed before)" in lines[0]
    assert not (out / store.FAILURES_NAME).exists() and "Incomplete" not in (out / "README.md").read_text()
    after = _episode_bytes(out)
    assert {k: after[k] for k in before} == before  # the stored episodes untouched

    # the recovered dataset is the one a run without faults gives, byte for byte
    gen.generate(spec, base, clean, workers=2, cache_dir=cache.root, progress=False, log=lambda m: None)
    reference = _episode_bytes(clean)
    assert set(reference) == set(after)
    for ep in reference:
        got, want = store.read_episode(out, ep), store.read_episode(clean, ep)
        for name in store.EPISODE_ARRAYS:
            if name in want:
                np.testing.assert_array_equal(got[name], want[name], err_msg=f"{ep} {name}")
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
