"""Exceptions that the CLI turns into exit codes (bad input: 2, failure: 1)."""

from __future__ import annotations

__all__ = ["MlsimError", "SceneError", "Problem", "MeshingError", "SolverError"]


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
