"""The scene model: shipped scenes load, bad input is refused with the field named, sweeps work."""

from __future__ import annotations

import re

import math
import subprocess
import sys
from pathlib import Path

import pytest

from mlsim.cli import main
from mlsim.errors import SceneError
from mlsim.materials import SHIPPED_MATERIALS, phosphor_relative_brightness
from mlsim.scene import Scene, load_scene, scene_from_dict
from fem.materials.shore_hardness import young_modulus_from_modulus_100, young_modulus_gent_pa

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ROOT / "scenes" / "mavig_default.toml"
TINY = ROOT / "scenes" / "mavig_tiny.toml"


def test_shipped_scenes_load_with_spec_values():
    scene = load_scene(DEFAULT)
    s = scene.sensor
    assert (s.rows, s.cols, s.n_rods) == (5, 5, 25)
    assert s.pitch_x_mm == pytest.approx(36.0 / 5)  # SPEC 1.1: pitch follows from the 36 mm width
    assert s.rod.diameter_mm == 5.0 and s.rod.height_mm == 9.0
    assert scene.load.indenter.tip_diameter_mm == pytest.approx(2 * math.sqrt(500 / math.pi))
    # press 1.5 mm at 10 mm/s + hold 0.1 s + slide 1.5 mm at 15 mm/s + rotate 6 deg at 60 deg/s + release 2 mm at 10 mm/s
    assert scene.load.duration_s == pytest.approx(0.15 + 0.1 + 0.1 + 0.1 + 0.2)
    tiny = load_scene(TINY)
    assert tiny.sensor.size_x_mm == pytest.approx(14.4)


def test_overrides_index_lists_either_way_and_bad_paths_say_how_to_fix():
    """``--set load.segments.2.speed_mm_s=...`` means ``load.segments[2]``; a list left unindexed, an
    index out of range or not an integer, and an index into a section are refused naming the path."""
    a = load_scene(DEFAULT, overrides={"load.segments.2.speed_mm_s": 100.0})
    b = load_scene(DEFAULT, overrides={"load.segments[2].speed_mm_s": 100.0})
    assert a.get("load.segments[2].speed_mm_s") == 100.0 and a.content_hash() == b.content_hash()
    cases = {
        "load.segments.speed_mm_s": r"load\.segments is a list: index it, e.g. load\.segments\[0\]\.speed_mm_s",
        "load.segments.9.speed_mm_s": r"index 9 is out of range: load\.segments has 5 entries",
        "load.segments[x].speed_mm_s": r"must be an integer",
        "sensor.rod[0]": r"sensor\.rod is a section, not a list",
    }
    for path, message in cases.items():
        with pytest.raises(SceneError, match=message):
            load_scene(DEFAULT, overrides={path: 1.0})


def test_scene_is_frozen_and_with_values_returns_a_new_valid_scene():
    scene = load_scene(DEFAULT)
    with pytest.raises(Exception):
        scene.sensor.rod.height_mm = 12.0
    taller = scene.with_values({"sensor.rod.height_mm": 12.0, "load.segments[2].speed_mm_s": 100.0})
    assert taller.sensor.rod.height_mm == 12.0 and scene.sensor.rod.height_mm == 9.0
    assert taller.get("load.segments[2].speed_mm_s") == 100.0
    assert taller.content_hash() != scene.content_hash()
    assert scene.with_values({}).content_hash() == scene.content_hash()
    with pytest.raises(SceneError, match=r"sensor\.rod\.height_mm = -1"):
        scene.with_values({"sensor.rod.height_mm": -1.0})


def test_content_hash_of_fields_ignores_other_fields():
    scene = load_scene(DEFAULT)
    paths = ("sensor.rod", "sensor.base")
    other = scene.with_values({"camera.gain_db": 12.0})
    assert other.content_hash(paths) == scene.content_hash(paths)
    assert other.content_hash() != scene.content_hash()


def test_material_resolution_and_override_provenance():
    scene = load_scene(DEFAULT)
    core = scene.material("core")
    assert core.name == "SC37" and "Gent" in core.young_modulus_pa.source
    changed = scene_from_dict({"materials": {"SC37": {"young_modulus_pa": 1.2e6}}})
    m = changed.material("core")
    assert m.young_modulus_pa.value == 1.2e6 and m.young_modulus_pa.source == "scene override"
    assert m.poisson_ratio.source == "SPEC 1.2"  # untouched values keep their provenance
    new = scene_from_dict(
        {"materials": {"myrubber": {"young_modulus_pa": 8e5, "poisson_ratio": 0.45, "density_kg_m3": 1000.0}},
         "sensor": {"materials": {"core": "myrubber"}}}
    )
    assert new.material("core").young_modulus_pa.value == 8e5


def test_shipped_materials_follow_spec_table():
    assert SHIPPED_MATERIALS["PDMS"].young_modulus_pa.value == 550e3
    assert SHIPPED_MATERIALS["SC37"].relative_ml_peak.value == 0.717
    assert all(SHIPPED_MATERIALS[n].poisson_ratio.value == 0.49 for n in ("PDMS", "SC37", "SC10", "DS30", "EF30"))
    # Harder silicone, stiffer: Shore 10A < 30A < 37A.
    e = [SHIPPED_MATERIALS[n].young_modulus_pa.value for n in ("SC10", "DS30", "SC37")]
    assert e[0] < e[1] < e[2]
    for mat in SHIPPED_MATERIALS.values():
        assert mat.young_modulus_pa.source and mat.density_kg_m3.source


def test_gent_relation_reference_values():
    # S = 0: E = 0.0981 * 56 / (0.137505 * 254) MPa, worked by hand.
    assert young_modulus_gent_pa(0.0) == pytest.approx(0.0981 * 56 / (0.137505 * 254) * 1e6, rel=1e-12)
    assert young_modulus_gent_pa(37.0) == pytest.approx(1.5072e6, rel=1e-4)
    with pytest.raises(ValueError, match="shore_a"):
        young_modulus_gent_pa(100.0)
    with pytest.raises(ValueError):
        young_modulus_gent_pa(float("nan"))


def test_modulus_100_round_trip_neo_hookean():
    e = young_modulus_from_modulus_100(69e3)
    shear = e / 3
    assert shear * (2.0 - 2.0**-2) == pytest.approx(69e3, rel=1e-12)  # nominal stress at stretch 2


def test_phosphor_brightness_table():
    assert phosphor_relative_brightness(60.0) == 1.0
    assert phosphor_relative_brightness(50.0) == pytest.approx(0.6224)
    assert phosphor_relative_brightness(55.0) == pytest.approx(0.5 * (1.0 + 0.6224))
    with pytest.raises(ValueError, match="20, 60"):
        phosphor_relative_brightness(70.0)


# ------------------------------------------------------------------------------------ bad input
BASE_LOAD = """
[load.indenter]
shape = "flat"
diameter_mm = 10.0
[[load.segments]]
kind = "press"
depth_mm = 1.0
speed_mm_s = 5.0
"""

BAD_SCENES = {
    "negative diameter": ("[sensor.rod]\ndiameter_mm = -5\n", "sensor.rod.diameter_mm = -5", "must be > 0"),
    "overlapping rods": ("[sensor.rod]\ndiameter_mm = 8.0\n", "sensor.rod.diameter_mm = 8.0", "overlap"),
    "unknown key": ("[sensor.rod]\ncolour = 'red'\n", "sensor.rod.colour", "valid keys here: diameter_mm, height_mm"),
    "unknown material": ("[sensor.materials]\ncore = 'Unobtainium'\n", "sensor.materials.core = 'Unobtainium'", "SC37"),
    "wrong type": ("[sensor]\nrows = 'five'\n", "sensor.rows = 'five'", "must be an integer"),
    "NaN": ("[sensor.rod]\nheight_mm = nan\n", "sensor.rod.height_mm = nan", "finite"),
    "infinite": ("[camera]\nfps = inf\n", "camera.fps = inf", "finite"),
    "layer thicker than rod radius": ("[sensor.layers]\nml_mm = 3.0\n", "sensor.layers.ml_mm = 3.0", "rod radius"),
    "zero rods": ("[sensor]\nrows = 0\n", "sensor.rows = 0", "must be >= 1"),
    "rod taller than the shell allows": ("[sensor.rod]\nheight_mm = 40.0\n", "sensor.rod.height_mm = 40.0", "above the camera"),
    "bool for a number": ("[sensor.rod]\ndiameter_mm = true\n", "sensor.rod.diameter_mm = True", "must be a number"),
    "unknown segment kind": (BASE_LOAD + "[[load.segments]]\nkind = 'wiggle'\n", "load.segments[1]", "choose one of"),
    "press with depth and force": (BASE_LOAD.replace("depth_mm = 1.0", "depth_mm = 1.0\nforce_n = 3.0"), "load.segments[0]", "exactly one of depth_mm"),
    "unknown output": ("outputs = ['mesh', 'hologram']\n", "outputs[1] = 'hologram'", "choose from"),
    "exposure longer than a frame": ("[camera]\nexposure_ms = 50.0\n", "camera.exposure_ms = 50.0", "frame period"),
    "pitch and surface size": ("[sensor]\npitch_mm = 7.0\nsurface_size_mm = 36.0\n", "sensor.pitch_mm = 7.0", "not both"),
    "new material without modulus": ("[materials.foam]\npoisson_ratio = 0.3\ndensity_kg_m3 = 50.0\n", "materials.foam.young_modulus_pa", "needs"),
    "negative seed": ("seed = -1\n", "seed = -1", "must be >= 0"),
    "element larger than a rod": ("[fidelity.mesh]\nedge_length_mm = 6.0\n", "fidelity.mesh.edge_length_mm = 6.0", "rod diameter"),
    "start off the surface": (BASE_LOAD + "[load]\n", None, None),  # placeholder replaced below
}
BAD_SCENES["start off the surface"] = (
    BASE_LOAD.replace("[load.indenter]", "[load]\nstart_xy_mm = [30.0, 0.0]\n[load.indenter]"),
    "load.start_xy_mm = [30.0, 0.0]",
    "start over the surface",
)


@pytest.mark.parametrize("case", sorted(BAD_SCENES))
def test_bad_scene_exits_2_and_names_the_field(case, tmp_path, capsys):
    text, path_and_value, hint = BAD_SCENES[case]
    scene = tmp_path / "bad.toml"
    scene.write_text(text)
    code = main(["check", str(scene)])
    err = capsys.readouterr().err
    assert code == 2, err
    assert path_and_value in err, err
    assert hint in err, err
    assert "Traceback" not in err


def test_invalid_toml_and_missing_file_exit_2(tmp_path, capsys):
    bad = tmp_path / "broken.toml"
    bad.write_text("[sensor\nrows = 5\n")
    assert main(["check", str(bad)]) == 2
    assert "not valid TOML" in capsys.readouterr().err
    assert main(["check", str(tmp_path / "nope.toml")]) == 2
    assert "no such scene file" in capsys.readouterr().err


def test_every_problem_is_reported_at_once():
    with pytest.raises(SceneError) as info:
        scene_from_dict({"sensor": {"rows": 0, "rod": {"diameter_mm": -1.0, "height_mm": float("nan")}}})
    paths = {p.path for p in info.value.problems}
    assert {"sensor.rows", "sensor.rod.diameter_mm", "sensor.rod.height_mm"} <= paths


def test_console_script_exit_code_and_no_traceback(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[sensor.rod]\ndiameter_mm = -5\n")
    proc = subprocess.run([sys.executable, "-m", "mlsim.cli", "check", str(bad)], capture_output=True, text=True, cwd=ROOT)
    assert proc.returncode == 2
    assert "sensor.rod.diameter_mm = -5: must be > 0" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_check_prints_resolved_scene_with_units(capsys):
    assert main(["check", str(DEFAULT)]) == 0
    out = capsys.readouterr().out
    assert "sensor.rod.height_mm" in out and "mm/s" in out and "wt%" in out
    assert "pitch                    = 7.2 x 7.2 mm" in out
    assert "Gent" in out  # provenance of the modulus


def test_set_override_on_the_command_line(capsys):
    assert main(["check", str(DEFAULT), "--set", "sensor.rod.height_mm=12"]) == 0
    assert re.search(r"^sensor\.rod\.height_mm +=  ?12\b", capsys.readouterr().out, re.M)
    assert main(["check", str(DEFAULT), "--set", "sensor.rod.height_mm=-3"]) == 2
    assert "sensor.rod.height_mm = -3" in capsys.readouterr().err


def test_default_scene_round_trips_through_dict():
    scene = load_scene(DEFAULT)
    again = scene_from_dict(scene.model_dump(mode="json", exclude_none=True))
    assert isinstance(again, Scene) and again.content_hash() == scene.content_hash()
