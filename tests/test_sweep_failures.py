"""mlsim sweep's failure paths (issue 38): a variant the scene model refuses and a load the tier
refuses are rows of the report with their reasons while the other rows keep their numbers; a NaN
figure is '-' in the table; an unknown ``--metrics`` name and a missing ``--load`` file are refused
before anything runs, naming what is wrong.

The sweeps run the tiny scene with one short press (one rod, 0.1 mm past contact) and the tear
metric only: about 10 s each on 2 cores, most of it the first solve."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import pytest

from mlsim.cli import EXIT_BAD_INPUT, main
from mlsim.scene import load_scene
from mlsim.sweep.report import write_report
from mlsim.sweep.run import METRICS, Load, stored_records, sweep
from mlsim.sweep.variants import parse_vary

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "scenes" / "mavig_tiny.toml"
# a flat probe over one rod, 0.1 mm past contact: the linear tier's cheapest solve that touches (0.33 N)
PRESS = Load("small_press", {"indenter": {"shape": "flat", "diameter_mm": 6.0}, "start_xy_mm": [3.6, 3.6], "start_gap_mm": 0.1,
                             "segments": [{"kind": "press", "depth_mm": 0.2, "speed_mm_s": 20.0}]}, {})


def _sweep(out: Path, cache_dir, vary: str, **kw) -> dict:
    return sweep(load_scene(TINY), parse_vary([vary]), out, loads=[PRESS], wanted=("tear",), cache_dir=cache_dir, progress=False,
                 log=lambda m: None, **kw)


def _csv_rows(out: Path) -> dict[str, dict]:
    with open(out / "sweep.csv", newline="") as f:
        return {row["label"]: row for row in csv.DictReader(f)}


def _md_rows(out: Path) -> tuple[list[str], dict[str, list[str]]]:
    """The Markdown table's header and its rows by their first cell (the varied value)."""
    lines = [line for line in (out / "sweep.md").read_text().splitlines() if line.startswith("| ")]
    cells = [[c.strip() for c in line.strip("|").split("|")] for line in lines]
    return cells[0], {row[0]: row for row in cells[1:]}


def test_a_refused_variant_is_a_row_with_its_reason_and_the_others_have_numbers(tmp_path, cache):
    """Rods 7.5 mm across at the 7.2 mm pitch overlap: that variant is stored unrun with the scene
    model's reason (naming the field and the fix), the report's failed column and 'What failed' list
    say "refused: ..." and its figures are empty / '-' (its tears too: nothing measured it, not "no");
    the 5 mm variant ran and has a positive strain and a safety factor."""
    out = tmp_path / "sw"
    summary = _sweep(out, cache.root, "sensor.rod.diameter_mm=5,7.5")
    assert summary["variants"] == 2 and summary["run_now"] == 1 and summary["complete"]
    recs = {r["label"]: r for r in stored_records(out).values()}
    bad = recs["diameter_mm=7.5"]
    assert not bad["buildable"] and bad["loads"] == {} and bad["scene_hash"] is None
    assert "rods overlap" in bad["reason"] and "sensor.rod.diameter_mm" in bad["reason"] and "sensor.pitch_mm" in bad["reason"]
    rows = _csv_rows(out)
    assert rows["diameter_mm=7.5"]["failed"] == f"refused: {bad['reason']}"
    assert rows["diameter_mm=7.5"]["small_press_strain_pct"] == "" and rows["diameter_mm=7.5"]["tears"] == ""
    good = rows["diameter_mm=5"]
    assert good["failed"] == "" and good["tears"] == "False"
    assert float(good["small_press_strain_pct"]) > 0 and float(good["small_press_sf_strain"]) > 1 and float(good["tear_risk"]) > 0
    header, md = _md_rows(out)
    strain = header.index("small_press_strain_pct")
    assert md["7.5"][strain] == "-" and md["7.5"][header.index("tears")] == "-" and md["7.5"][header.index("tear_risk")] == "-"
    assert float(md["5"][strain]) == pytest.approx(float(good["small_press_strain_pct"]), rel=1e-3)
    assert md["5"][header.index("tears")] == "no"
    assert f"- diameter_mm=7.5: refused: {bad['reason']}" in (out / "sweep.md").read_text()


def test_a_load_the_tier_refuses_is_reported_failed_and_the_sweep_finishes_the_others(tmp_path, cache):
    """small_strain_limit = 0.001 (9 um on the 9 mm rods) with escalation off: the linear tier refuses
    the press at its first contact step. That variant's load is stored as failed with the solver's
    reason (the field and the fix), it is not retried (no "retry"), and the report's failed column
    says which load; the variant at the default limit, run in the same sweep, has its numbers."""
    out = tmp_path / "sw"
    summary = _sweep(out, cache.root, "fidelity.solve.small_strain_limit=0.5,0.001", escalate_to=None)
    assert summary["run_now"] == 2 and summary["complete"] and summary["killed"] == []
    recs = {r["label"]: r for r in stored_records(out).values()}
    failed = recs["small_strain_limit=0.001"]
    assert failed["buildable"] and not failed.get("retry")
    r = failed["loads"]["small_press"]
    assert not r["ok"] and r["reason"].startswith("OutOfRangeError: ")
    assert "beyond fidelity.solve.small_strain_limit = 0.001" in r["reason"] and "raise small_strain_limit" in r["reason"]
    ok = recs["small_strain_limit=0.5"]["loads"]["small_press"]
    assert ok["ok"] and ok["solve_tier"] == "linear" and ok["peak_normal_force_n"] > 0.1 and ok["peak_principal_strain_pct"] > 0
    rows = _csv_rows(out)
    assert rows["small_strain_limit=0.001"]["failed"] == f"small_press: {r['reason']}"
    assert rows["small_strain_limit=0.001"]["small_press_force_n"] == "" and rows["small_strain_limit=0.001"]["tears"] == ""
    # the cantilever sensitivity needs no solve: the failed variant still has it
    assert float(rows["small_strain_limit=0.001"]["beam_strain_per_n"]) == pytest.approx(float(rows["small_strain_limit=0.5"]["beam_strain_per_n"]))
    assert rows["small_strain_limit=0.5"]["failed"] == ""
    assert float(rows["small_strain_limit=0.5"]["small_press_force_n"]) == pytest.approx(ok["peak_normal_force_n"])
    assert f"- small_strain_limit=0.001: small_press: {r['reason']}" in (out / "sweep.md").read_text()


def test_a_nan_figure_is_a_dash_in_the_table_and_nan_in_the_csv(tmp_path):
    """A record whose strain and error estimate are NaN (and a neighbour whose are not): the
    Markdown table (what `mlsim sweep` prints) shows '-' there, never 'nan', while the neighbour's
    cells and the NaN row's finite cells keep their numbers; the CSV keeps the NaN (it reads back as
    NaN, not as a number and not as a missing value that hides it)."""
    varies = parse_vary(["sensor.rod.height_mm=9,12"])
    load = {"ok": True, "solve_tier": "linear", "escalated": None, "peak_normal_force_n": 0.5, "peak_principal_stress_kpa": 3.0,
            "peak_principal_strain_pct": 0.7, "safety_factor_stress": 8000.0, "safety_factor_strain": 250.0, "tears": False,
            "solve_error_estimate": 1e-5}
    records = [{"variant_id": f"v00{i}_00000000", "label": f"height_mm={h}", "values": {"sensor.rod.height_mm": h}, "buildable": True,
                "reason": None, "beam_strain_per_n": 0.5, "seconds": 1.0, "loads": {"small_press": dict(load)}}
               for i, h in enumerate((9, 12))]
    records[1]["loads"]["small_press"].update(peak_principal_strain_pct=math.nan, solve_error_estimate=math.nan)
    meta = {"base_scene": {"name": "mavig_tiny"}, "varies": [{"path": v.path, "values": list(v.values)} for v in varies],
            "loads": [{"name": "small_press"}], "metrics": ["tear"], "angles_deg": []}
    write_report(tmp_path, records, varies, meta, {"stored": 2, "variants": 2})
    text = (tmp_path / "sweep.md").read_text()
    assert "nan" not in text.lower()
    header, md = _md_rows(tmp_path)
    strain, err = header.index("small_press_strain_pct"), header.index("small_press_force_err_est")
    assert md["12"][strain] == "-" and md["12"][err] == "-"
    assert md["9"][strain] == "0.7" and md["9"][err] == "1e-05"
    assert md["12"][header.index("small_press_stress_kpa")] == "3" and md["12"][header.index("tear_risk")] == "0.004"  # 1 / 250
    rows = _csv_rows(tmp_path)
    assert math.isnan(float(rows["height_mm=12"]["small_press_strain_pct"])) and math.isnan(float(rows["height_mm=12"]["small_press_force_err_est"]))
    assert float(rows["height_mm=9"]["small_press_strain_pct"]) == 0.7
    assert "failed" not in rows["height_mm=12"]  # a NaN figure is not a failure: no row has one, so no column


def test_a_load_the_rods_collapse_under_is_recorded_with_its_collapse_load_and_not_escalated(tmp_path, monkeypatch):
    """The held Cosserat rods collapsing under a load (mlsim.errors.RodCollapseError: the sweep's 5 N press on
    12 x 3 mm rods gave way at 3.26 N) is the variant's answer to it: the record keeps the load the rods collapse at
    and the step, it is not handed to the nonlinear tier (a dead load past the collapse snaps through: hours on that
    tier), and the report shows the load in its ``collapse_n`` column and the reason in what failed."""
    from mlsim.errors import RodCollapseError
    from mlsim.sweep import run as sweep_run

    asked = []

    def collapsing(scene, cache_dir, outputs):
        asked.append(scene.fidelity.solve.tier)
        raise RodCollapseError("step 89 (t = 197.8 ms): the rods collapse: after the last step that converged, at 3.258 N ...", 3.258, 89)

    monkeypatch.setattr(sweep_run, "_run", collapsing)
    scene = load_scene(TINY).with_values({"fidelity.solve.tier": "reduced", "fidelity.solve.rod_kinematics": "cosserat",
                                          "fidelity.solve.rod_coupling": "held"})
    r = sweep_run._load_metrics(scene, PRESS, tmp_path, ("tear",), escalate_to="nonlinear")
    assert asked == ["reduced"]  # not escalated
    assert not r["ok"] and r["collapse_force_n"] == 3.258 and r["collapse_step"] == 89 and r["escalated"] is None
    assert r["reason"].startswith("RodCollapseError: step 89 (t = 197.8 ms): the rods collapse")
    varies = parse_vary(["sensor.rod.height_mm=12"])
    records = [{"variant_id": "v000_00000000", "label": "height_mm=12", "values": {"sensor.rod.height_mm": 12.0}, "buildable": True,
                "reason": None, "beam_strain_per_n": 0.5, "seconds": 1.0, "loads": {"small_press": r}}]
    meta = {"base_scene": {"name": "mavig_tiny"}, "varies": [{"path": v.path, "values": list(v.values)} for v in varies],
            "loads": [{"name": "small_press"}], "metrics": ["tear"], "angles_deg": []}
    write_report(tmp_path, records, varies, meta, {"stored": 1, "variants": 1})
    row = _csv_rows(tmp_path)["height_mm=12"]
    assert float(row["small_press_collapse_n"]) == 3.258 and "small_press_force_n" not in row  # no figure of the load
    assert row["failed"] == f"small_press: the rods collapse at 3.26 N: {r['reason']}"
    header, md = _md_rows(tmp_path)
    assert md["12"][header.index("small_press_collapse_n")] == "3.258"


def _cli(tmp_path, capsys, *extra) -> tuple[int, str]:
    code = main(["sweep", str(TINY), "--vary", "sensor.rod.height_mm=9", "--out", str(tmp_path / "sw"), "--cache", str(tmp_path / "cache"),
                 "--quiet", *extra])
    return code, capsys.readouterr().err


@pytest.mark.parametrize("dry_run", [False, True])
def test_an_unknown_metric_is_refused_before_anything_runs(tmp_path, capsys, dry_run):
    """--metrics tear,brightnes: exit 2 (bad input) with one line naming the flag and the bad name
    only, and the valid names; no output folder (the sweep did not start), and a dry run refuses it
    too instead of pricing the known metrics. An empty list is refused the same way."""
    extra = ["--dry-run"] if dry_run else []
    code, err = _cli(tmp_path, capsys, "--metrics", "tear,brightnes", *extra)
    assert code == EXIT_BAD_INPUT
    assert "--metrics = 'brightnes': unknown metric; choose from: " + ", ".join(METRICS) in err
    assert "Traceback" not in err and not (tmp_path / "sw").exists()
    code, err = _cli(tmp_path, capsys, "--metrics", ",", *extra)
    assert code == EXIT_BAD_INPUT and "--metrics = '': no metric given; choose from: brightness" in err
    assert not (tmp_path / "sw").exists()


@pytest.mark.parametrize("flag, metrics", [("--load", "tear"), ("--direction-scene", "direction")])
def test_a_missing_or_unreadable_load_file_is_refused_naming_the_flag_and_path(tmp_path, capsys, flag, metrics):
    """A --load (or --direction-scene) file that does not exist, or is not TOML: exit 2 with the
    flag that named it and its whole path (and the TOML error's line), no traceback, nothing
    written; a dry run refuses it too."""
    missing = tmp_path / "no_such_load.toml"
    for extra in ([], ["--dry-run"]):
        code, err = _cli(tmp_path, capsys, "--metrics", metrics, flag, str(missing), *extra)
        # the value is cut at 60 characters in the error; the message has the whole path
        assert code == EXIT_BAD_INPUT and f"{flag} = " in err and f"no such scene file (looked for {missing})" in err
        assert "Traceback" not in err and not (tmp_path / "sw").exists()
    broken = tmp_path / "broken.toml"
    broken.write_text("[load\nindenter = 1\n")
    code, err = _cli(tmp_path, capsys, "--metrics", metrics, flag, str(broken))
    assert code == EXIT_BAD_INPUT and f"{flag} = " in err and f"{broken} is not a TOML scene file: " in err and "line 1" in err
    assert "Traceback" not in err and not (tmp_path / "sw").exists()
