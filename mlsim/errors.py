"""Exceptions that the CLI turns into exit codes (bad input: 2, failure: 1)."""

from __future__ import annotations

__all__ = ["MlsimError", "SceneError", "Problem", "MeshingError", "SolverError", "OutOfRangeError", "RodCollapseError", "require_finite"]


class MlsimError(RuntimeError):
    """A failure that mlsim explains itself (exit code 1): no traceback is shown to the user."""


class Problem(tuple):
    """One problem of a scene: (dotted path, value received, what is valid)."""

    __slots__ = ()

    def __new__(cls, path: str, value, message: str):
        return super().__new__(cls, (path, value, message))

    @property
    def path(self) -> str:
        return self[0]

    @property
    def value(self):
        return self[1]

    @property
    def message(self) -> str:
        return self[2]

    def __str__(self) -> str:
        return f"{self.path} = {_show(self.value)}: {self.message}"


def _show(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


class SceneError(ValueError):
    """A scene that does not validate (exit code 2). Holds every problem found, each naming its path."""

    def __init__(self, problems, source: str | None = None):
        self.problems = [p if isinstance(p, Problem) else Problem(*p) for p in problems]
        self.source = source
        head = f"invalid scene{f' {source}' if source else ''}"
        super().__init__(head + ":\n" + "\n".join(f"  {p}" for p in self.problems))


class MeshingError(MlsimError):
    """Tetrahedral meshing failed after every retry."""


class SolverError(MlsimError):
    """A nonlinear solve that did not converge (names the case, load factor and residual)."""


class OutOfRangeError(SolverError):
    """A fast tier (``linear``, ``reduced``) refusing a load beyond the range of its model: a contact
    point moved past ``small_strain_limit`` of the rod height, or a rod loaded past ``buckling_limit``
    of its Euler load. The ``nonlinear`` tier answers such loads (``mlsim sweep`` hands them to it)."""


class RodCollapseError(OutOfRangeError):
    """A fast tier's held Cosserat rods collapsing (a step that failed after its contact rounds loaded a rod past
    its free Euler load): the load the sensor carried at the last step that converged (``force_n``, N) and the
    step that failed (``step``). Past that point a dead load snaps through; following it needs the nonlinear
    tier with dynamics. ``mlsim sweep`` records the collapse load as the answer, not as a failure."""

    def __init__(self, message: str, force_n: float, step: int):
        super().__init__(message)
        self.force_n = float(force_n)
        self.step = int(step)


def require_finite(array, what: str, fix: str, error: type[Exception] = ValueError) -> None:
    """Refuse an array with a NaN or an infinity before it reaches a compiled kernel.

    The numba kernels (the rasteriser, the transport product, the ADMM contact iterations) would
    carry a NaN silently into every pixel or force it touches, or clamp it away where a min/max
    meets it; so their entry points check first. ``what`` names the array and its shape's meaning
    ("radiance (frames, vertices)"); the message gives how many entries are bad, where the first
    one is, and ``fix``. ``error``: the class raised (ValueError for arguments, SolverError inside
    a solve)."""
    import numpy as np

    a = np.asarray(array)
    finite = np.isfinite(a)
    if finite.all():
        return
    bad = np.argwhere(~finite)
    first = tuple(int(i) for i in bad[0])
    raise error(f"{what}: {len(bad)} of {a.size} entries are NaN or infinite (the first at index {first}, "
                f"{a[first]!r}); {fix}")
