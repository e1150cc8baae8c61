"""The command line's one grammar (issue 42, mlsim.cli_grammar): every verb takes its scene (spec,
dataset) first and the shared flags its table names, with the same defaults; every verb's --help ends
with examples that parse; --version; --outputs lists its choices; --dry-run runs nothing; trained
models go to --out, never into scenes/."""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path

import pytest

from mlsim.cli import build_parser, main
from mlsim.cli_grammar import EXAMPLES, SHARED_FLAGS, default_workers

ROOT = Path(__file__).resolve().parents[1]


def verbs() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(sub.choices)


def options(p: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    return {s: a for a in p._actions for s in a.option_strings}


def test_every_verb_is_in_the_grammar_table():
    assert set(verbs()) == set(SHARED_FLAGS) == set(EXAMPLES)


@pytest.mark.parametrize("verb", sorted(SHARED_FLAGS))
def test_every_verb_takes_its_shared_flags_with_the_same_defaults(verb):
    p = verbs()[verb]
    opts = options(p)
    for flag in SHARED_FLAGS[verb]:
        assert flag in opts, f"mlsim {verb} lacks {flag}"
    positional = [a for a in p._actions if not a.option_strings and a.dest != "help"]
    assert [a.metavar for a in positional] in (["SCENE"], ["SPEC"], ["DATASET"], ["RECORDING"]), verb
    if positional[0].metavar == "RECORDING":  # mlsim detect: a recording first, its (optional) scene by --scene
        assert "--scene" in opts and opts["--scene"].default is None, verb
    for flag in ("--dry-run", "--quiet"):
        if flag in opts:
            assert isinstance(opts[flag], argparse._StoreTrueAction) and opts[flag].default is False
    if "--cache" in opts:
        assert opts["--cache"].default is None  # the shared default: $MLSIM_CACHE_DIR or ~/.cache/mlsim
    if "--out" in opts:
        assert opts["--out"].default is None and "default out/" in opts["--out"].help
    if "--workers" in opts:
        training = verb in ("train", "ablation", "anyskin-train")  # torch threads: one, so that weights reproduce
        assert opts["--workers"].default == (1 if training else default_workers()), verb


@pytest.mark.parametrize("verb", sorted(EXAMPLES))
def test_every_verbs_help_ends_with_examples_that_parse(verb, capsys):
    assert main([verb, "--help"]) == 0
    help_text = capsys.readouterr().out
    assert "examples:\n" in help_text
    examples = help_text.split("examples:\n", 1)[1].strip().splitlines()
    assert examples and all(line.strip().startswith(f"mlsim {verb} ") for line in examples)
    parser = build_parser()
    for line in examples:
        args = parser.parse_args(shlex.split(line.strip())[1:])  # exits 2 on an example that does not parse
        assert args.command == verb


def test_version(capsys):
    from mlsim import __version__

    assert main(["--version"]) == 0 and capsys.readouterr().out.strip() == f"mlsim {__version__}"


def test_outputs_help_lists_every_kinds_outputs(capsys):
    from mlsim.stage import kinds, outputs

    assert main(["run", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())  # argparse wraps lines
    for k in kinds():
        assert f"{k}: {', '.join(outputs(k))}" in text


def test_a_bad_output_is_refused_with_the_choices(capsys):
    code = main(["run", str(ROOT / "scenes" / "mavig_tiny.toml"), "--outputs", "nonsense", "--dry-run"])
    err = capsys.readouterr().err
    assert code == 2 and "--outputs = 'nonsense'" in err and "choose from: geometry, mesh" in err


def test_mesh_and_run_write_to_different_default_folders(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    scene = str(ROOT / "scenes" / "mavig_tiny.toml")
    assert main(["mesh", scene, "--quiet"]) == 0
    assert main(["run", scene, "--outputs", "geometry", "--quiet"]) == 0
    assert (tmp_path / "out" / "mavig_tiny_mesh" / "mesh.vtu").is_file()
    assert (tmp_path / "out" / "mavig_tiny" / "surface_outer.ply").is_file()
    assert not (tmp_path / "out" / "mavig_tiny" / "mesh.vtu").exists()


def test_dry_runs_run_nothing(tmp_path, monkeypatch, capsys):
    """The long verbs' --dry-run print their plan and write nothing; the counts are the grid's."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "scenes").symlink_to(ROOT / "scenes")
    assert main(["dataset", "scenes/interactions/small.toml", "--set", "samples_per_action=4", "--dry-run"]) == 0
    assert "32 episodes" in capsys.readouterr().out  # 8 actions x 4
    assert main(["sweep", "scenes/mavig_tiny.toml", "--vary", "sensor.rod.height_mm=6,9", "--vary", "sensor.rod.diameter_mm=3,8",
                 "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "4 variant(s)" in out and out.count("refused: ") == 2 and out.count("to run") == 2  # 8 mm rods overlap at 7.2 mm pitch
    assert main(["accuracy", "scenes/mavig_tiny.toml", "--edges", "3", "2.5", "--orders", "2", "--dry-run"]) == 0
    assert "6 run(s)" in capsys.readouterr().out  # 2 edges x 1 order x 3 tiers
    assert main(["direction", "scenes/mavig_tiny.toml", "--angles", "0", "90", "--dry-run"]) == 0
    assert "2 run(s)" in capsys.readouterr().out
    assert not (tmp_path / "out").exists()


def test_dataset_set_refuses_nested_fields(capsys):
    code = main(["dataset", str(ROOT / "scenes" / "interactions" / "small.toml"), "--set", "interaction.grip_force_n=2", "--dry-run"])
    err = capsys.readouterr().err
    assert code == 2 and "--set = 'interaction.grip_force_n'" in err and "top-level" in err


def test_trained_models_go_to_out_never_into_scenes():
    for verb in ("train", "ablation", "anyskin-train", "evaluate"):
        out = options(verbs()[verb])["--out"]
        assert out.default is None and "scenes/" not in out.help
    from mlsim.studies import anyskin_cli, classifier_cli

    for module in (anyskin_cli, classifier_cli):
        source = Path(module.__file__).read_text()
        assert 'Path("scenes")' not in source and "scenes/anyskin/models" not in source.split("def add_parsers")[0]


def test_old_threads_flag_still_sets_the_workers():
    args = build_parser().parse_args(["train", "out/x", "--threads", "3"])
    assert args.workers == 3
    assert build_parser().parse_args(["train", "out/x"]).workers == 1
