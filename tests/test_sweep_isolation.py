"""A sweep survives a variant whose process is killed (issue 39): the others finish, the killed one is
stored with its reason (the signal), the report says so, and a rerun runs only that one."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

from mlsim.scene import load_scene
from mlsim.sweep.isolated import failure_record
from mlsim.sweep.run import read_load, stored_records, sweep
from mlsim.sweep.variants import parse_vary

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "scenes" / "mavig_tiny.toml"


def _tiny_sweep(out: Path, cache_dir):
    # not escalated: the tiny load's first-order answer (estimated 175 % off) would go to the nonlinear tier, 22 s a
    # variant, and this is a test of the sweep's process isolation
    return sweep(load_scene(TINY), parse_vary(["sensor.materials.core=SC37,PDMS"]), out, loads=[read_load(TINY)], wanted=("tear",),
                 cache_dir=cache_dir, progress=False, log=lambda m: None, escalate_to=None)


def _command_lines():
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                yield int(entry.name), (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            except OSError:
                continue


def _kill_first(marker: str, killed: list, stop: threading.Event) -> None:
    """SIGKILL the first process whose command line holds ``marker`` (one variant's own process)."""
    while not stop.is_set():
        for pid, cmd in _command_lines():
            if "mlsim.sweep.isolated" in cmd and marker in cmd:
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
                return
        time.sleep(0.02)


def test_a_killed_variant_is_reported_and_a_rerun_runs_only_it(tmp_path, cache):
    out = tmp_path / "sw"
    killed: list = []
    stop = threading.Event()
    watcher = threading.Thread(target=_kill_first, args=("core=PDMS", killed, stop), daemon=True)
    watcher.start()
    try:
        summary = _tiny_sweep(out, cache.root)
    finally:
        stop.set()
        watcher.join()
    assert len(killed) == 1
    records = {r["values"]["sensor.materials.core"]: r for r in stored_records(out).values()}
    assert records["SC37"]["loads"]["mavig_tiny"]["ok"] and not records["SC37"].get("retry")
    pdms = records["PDMS"]
    assert pdms["retry"] and "killed by SIGKILL" in pdms["reason"] and pdms["loads"] == {}
    assert summary["killed"] == [pdms["variant_id"]] and not summary["complete"] and summary["run_now"] == 2
    assert "killed by SIGKILL" in (out / "sweep.md").read_text()
    sc37 = (out / "variants" / f"{records['SC37']['variant_id']}.json").read_bytes()
    rerun = _tiny_sweep(out, cache.root)
    assert rerun["run_now"] == 1 and rerun["complete"] and rerun["killed"] == []
    assert (out / "variants" / f"{records['SC37']['variant_id']}.json").read_bytes() == sc37  # untouched
    again = {r["values"]["sensor.materials.core"]: r for r in stored_records(out).values()}["PDMS"]
    assert again["loads"]["mavig_tiny"]["ok"] and not again.get("retry")


def test_failure_record_names_the_signal_or_the_exit():
    rec = failure_record(-signal.SIGKILL, "", 1.23456)
    assert rec["retry"] and "SIGKILL" in rec["reason"] and "out-of-memory" in rec["reason"] and rec["seconds"] == 1.235
    assert "SIGTERM" in failure_record(-signal.SIGTERM, "", 0)["reason"]
    rec = failure_record(1, "Traceback (most recent call last):\n  ...\nMemoryError: Unable to allocate 335. GiB\n", 0)
    assert "exited with code 1" in rec["reason"] and "MemoryError: Unable to allocate 335. GiB" in rec["reason"]
