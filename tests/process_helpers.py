"""Running a command until a condition holds, then killing it (the kill-and-resume tests)."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from typing import Callable

import pytest


def kill_when(cmd: list[str], done: Callable[[], bool], timeout_s: float = 240.0, what: str = "the condition") -> None:
    """Start ``cmd`` in its own session, wait until ``done()``, then SIGKILL its whole process group
    (workers included). Fails the test if the command ends first or ``timeout_s`` passes."""
    proc = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + timeout_s
    try:
        while not done():
            if proc.poll() is not None:
                pytest.fail(f"the run ended before it could be killed: {proc.stderr.read().decode()[-2000:]}")
            if time.monotonic() > deadline:
                pytest.fail(f"no {what} within {timeout_s:g} s")
            time.sleep(0.05)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
