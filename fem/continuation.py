"""Step halving along an indenter's path: the one continuation driver of the contact tiers.

A quasi-static step moves the indenter from ``pose_old`` to ``pose``. When the step fails (its solver
raises :class:`fem.nonlinear.SolverError`), when it would jump the indenter deeper into the body than
a penalty ever lets it sink (``jumps``: a thin indenter can tunnel past a point that the penalty
then pushes out of the far side), or when its answer has a point sunk too deep (``too_deep``), the
move is split at its midpoint and both halves are solved in turn, the second from the first's end,
recursively down to 1 / 2^max_depth of the move. Friction is path-dependent, so the halves are
solved in order and their results chained, never averaged.

Used by :func:`fem.condensed.solve_path` (the linear and reduced tiers, with either contact solver)
and :meth:`fem.finite_strain.NonlinearContact.path` (the nonlinear tier).
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from fem.indenters import Pose
from fem.nonlinear import SolverError
from mlsim.errors import OutOfRangeError

__all__ = ["midpoint", "solve_with_halving"]


def midpoint(pose_old: Pose, pose: Pose) -> Pose:
    """The pose halfway between two (position and yaw, linearly)."""
    return Pose(tuple(0.5 * (np.asarray(pose.position_m) + np.asarray(pose_old.position_m))), 0.5 * (pose.yaw_rad + pose_old.yaw_rad))


def solve_with_halving(step: Callable[[Pose, Pose, Any, bool], Any], pose_old: Pose, pose: Pose, start: Any, max_depth: int = 8, *,
                       jumps: Callable[[Pose, Any], bool] | None = None, too_deep: Callable[[Any], str | None] | None = None,
                       deep_at_the_end: str = "return", next_start: Callable[[Any], Any] = lambda result: result,
                       chain: Callable[[Any, Any], Any] = lambda first, second: second,
                       unsettled: Callable[[Any], bool] | None = None, unsettled_cuts: int = 0):
    """Solve the move ``pose_old`` -> ``pose`` from ``start``, halving it where needed (module docstring).

    step(pose_old, pose, start, whole) -> result: one solve (``whole``: the move as asked, not a half
    of it: a caller may use a starting guess only then); jumps(pose, start): the move would jump too
    deep (checked while halving is still allowed); too_deep(result): None, or what is too deep about
    the answer; next_start(result): the start of the next half from a half's result;
    chain(first, second): the result of two halves (default: the second's). At ``max_depth`` 0 a
    failure is raised, and a deep answer returned as it is (``deep_at_the_end = "return"``) or
    refused with a :class:`SolverError` (``"raise"``).

    unsettled(result): the answer stands but its solver did not settle (an iterative coupling that ran out
    of its budget); such a move is split too, at most ``unsettled_cuts`` levels deep. There ``step`` is
    called with ``final``: True where no such cut is left (the solver may spend its last resort), and
    an answer that still did not settle is returned as it is."""
    if deep_at_the_end not in ("return", "raise"):
        raise ValueError(f'deep_at_the_end = "{deep_at_the_end}": choose "return" or "raise"')
    hooks = (jumps, too_deep, deep_at_the_end, next_start, chain, unsettled)
    return _solve(step, pose_old, pose, start, max_depth, unsettled_cuts if unsettled is not None else 0, True, hooks)


def _solve(step, pose_old, pose, start, depth, cuts, whole, hooks):
    jumps, too_deep, deep_at_the_end, next_start, chain, unsettled = hooks
    if not (depth > 0 and jumps is not None and jumps(pose, start)):
        try:
            can_cut = depth > 0 and cuts > 0
            result = step(pose_old, pose, start, whole) if unsettled is None else step(pose_old, pose, start, whole, final=not can_cut)
            deep = None if too_deep is None else too_deep(result)
            if deep is None:
                if not (can_cut and unsettled(result)):
                    return result
            elif depth <= 0:
                if deep_at_the_end == "raise":
                    raise SolverError(deep)
                return result
        except OutOfRangeError:
            raise  # a model's range, not a step too long: halving cannot help
        except SolverError:
            if depth <= 0:
                raise
    mid = midpoint(pose_old, pose)
    first = _solve(step, pose_old, mid, start, depth - 1, cuts - 1, False, hooks)
    second = _solve(step, mid, pose, next_start(first), depth - 1, cuts - 1, False, hooks)
    return chain(first, second)
