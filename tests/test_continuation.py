"""fem.continuation.solve_with_halving: the cuts a move takes, in order, and what each piece is told.

A stand-in step records the moves it is asked to solve; the checks are on the pieces (their lengths and
order along the path) and on the ``final`` flag that lets a solver spend its last resort only where no cut
is left (fem.condensed.solve_path's held Cosserat rods)."""
import pytest

from fem.continuation import solve_with_halving
from fem.indenters import Pose
from fem.nonlinear import SolverError


def _recording_step(settles_below_m: float, fails_above_m: float = float("inf")):
    calls = []

    def step(p_old, p, start, whole, **kw):
        length = p.position_m[0] - p_old.position_m[0]
        calls.append((round(p_old.position_m[0], 9), round(p.position_m[0], 9), whole, kw.get("final")))
        if length > fails_above_m:
            raise SolverError("too long")
        return {"to": p.position_m[0], "settled": length <= settles_below_m, "pieces": [(p_old.position_m[0], p.position_m[0])]}

    return step, calls


def _chain(first, second):
    return {"to": second["to"], "settled": first["settled"] and second["settled"], "pieces": first["pieces"] + second["pieces"]}


A, B = Pose((0.0, 0.0, 0.0), 0.0), Pose((1.0, 0.0, 0.0), 0.0)


def test_unsettled_move_is_cut_to_quarters_in_order():
    step, calls = _recording_step(settles_below_m=0.3)
    out = solve_with_halving(step, A, B, None, 8, chain=_chain, unsettled=lambda r: not r["settled"], unsettled_cuts=2)
    assert out["settled"] and out["to"] == 1.0
    assert out["pieces"] == [(0.0, 0.25), (0.25, 0.5), (0.5, 0.75), (0.75, 1.0)]
    # depth first: the whole move and each half are told a cut is left (final False), the quarters that none is
    assert [c[3] for c in calls] == [False, False, True, True, False, True, True]
    assert [c[:2] for c in calls] == [(0.0, 1.0), (0.0, 0.5), (0.0, 0.25), (0.25, 0.5), (0.5, 1.0), (0.5, 0.75), (0.75, 1.0)]
    assert calls[0][2] is True and all(c[2] is False for c in calls[1:])


def test_a_move_that_never_settles_is_returned_at_the_last_cut():
    step, calls = _recording_step(settles_below_m=0.0)
    out = solve_with_halving(step, A, B, None, 8, chain=_chain, unsettled=lambda r: not r["settled"], unsettled_cuts=2)
    assert not out["settled"] and len(out["pieces"]) == 4  # not cut below a quarter, not raised
    assert len(calls) == 1 + 2 + 4


def test_settled_move_is_not_cut_and_no_hook_means_no_final_flag():
    step, calls = _recording_step(settles_below_m=2.0)
    out = solve_with_halving(step, A, B, None, 8, chain=_chain, unsettled=lambda r: not r["settled"], unsettled_cuts=2)
    assert out["pieces"] == [(0.0, 1.0)] and calls == [(0.0, 1.0, True, False)]
    step, calls = _recording_step(settles_below_m=0.0)
    out = solve_with_halving(step, A, B, None, 8, chain=_chain)  # an unsettled answer without the hook stands
    assert out["pieces"] == [(0.0, 1.0)] and calls == [(0.0, 1.0, True, None)]


def test_failures_still_cut_to_max_depth_and_raise_there():
    step, calls = _recording_step(settles_below_m=2.0, fails_above_m=0.2)
    out = solve_with_halving(step, A, B, None, 3, chain=_chain, unsettled=lambda r: not r["settled"], unsettled_cuts=1)
    assert [round(b - a, 9) for a, b in out["pieces"]] == [0.125] * 8  # failures cut past the unsettled levels
    step, _ = _recording_step(settles_below_m=2.0, fails_above_m=0.01)
    with pytest.raises(SolverError):
        solve_with_halving(step, A, B, None, 3, chain=_chain, unsettled=lambda r: not r["settled"], unsettled_cuts=1)
