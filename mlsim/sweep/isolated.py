"""One job in a process of its own, so that a job the kernel kills (out of memory) or that a signal
stops is a failed result with its reason, and the worker that ran it goes on to the next (issue 39).

:func:`run_isolated` writes the job as JSON, runs ``python -m mlsim.sweep.isolated FN JOB RESULT
LABEL`` (the label in the command line names the job to ``ps``, and to a test that kills it), and
reads the result back. A child that ends without a result gives :class:`Killed`'s record: the
signal's name or the exit code and the last line of its error output. The child inherits the
worker's environment (its thread limits, the cache directory).

The price is a fresh interpreter per job (about a second of imports, and the in-process memo of
per-sensor objects is not shared between jobs): a sweep's variant takes minutes.
"""

from __future__ import annotations

import importlib
import json
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

__all__ = ["run_isolated", "failure_record"]


def failure_record(returncode: int, stderr: str, seconds: float) -> dict:
    """The record of a job whose process ended without a result: why, and that a rerun retries it."""
    if returncode < 0:
        name = signal.Signals(-returncode).name if -returncode in signal.Signals._value2member_map_ else f"signal {-returncode}"
        why = f"its process was killed by {name}" + (" (the kernel's out-of-memory killer sends it, as does kill -9)" if name == "SIGKILL" else "")
    else:
        last = [line for line in stderr.strip().splitlines() if line.strip()][-1:] or ["no error output"]
        why = f"its process exited with code {returncode} without a result: {last[0][:300]}"
    return {"loads": {}, "seconds": round(seconds, 3), "reason": f"killed: {why}; a rerun of the same command retries it", "retry": True}


def run_isolated(fn: str, job: dict, label: str) -> dict:
    """``fn(job)`` (``fn`` as "module:function") in a child process; its result, or the
    :func:`failure_record` of a child that died."""
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="mlsim_job_") as tmp:
        job_path, result_path = Path(tmp) / "job.json", Path(tmp) / "result.json"
        job_path.write_text(json.dumps(job))
        proc = subprocess.run([sys.executable, "-m", "mlsim.sweep.isolated", fn, str(job_path), str(result_path), label],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        if proc.returncode == 0 and result_path.is_file():
            return json.loads(result_path.read_text())
    return failure_record(proc.returncode, proc.stderr or "", time.perf_counter() - t0)


def _main(argv: list[str]) -> int:
    fn, job_path, result_path = argv[0], Path(argv[1]), Path(argv[2])
    module, name = fn.split(":")
    result = getattr(importlib.import_module(module), name)(json.loads(job_path.read_text()))
    tmp = result_path.with_suffix(".tmp")
    tmp.write_text(json.dumps(result, default=lambda v: v.tolist() if hasattr(v, "tolist") else str(v)))  # numpy scalars and arrays
    tmp.replace(result_path)  # whole or not at all
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
