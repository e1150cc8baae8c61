"""Command line: ``mlsim run | check | mesh | accuracy | direction | ambient | dataset | sweep | detect | calibrate | train |
evaluate | ablation | anyskin-train``, and ``mlsim --version``.

One grammar (:mod:`mlsim.cli_grammar`): the scene (or spec, or dataset, or ``detect``'s recording) first, then the shared flags
``--set``, ``--dry-run``, ``--out``, ``--workers``, ``--cache``, ``--quiet`` where they make sense, with
the same defaults; every verb's ``--help`` ends with examples.

Exit codes: 0 success, 2 bad input (an invalid scene or argument; the message names the field),
1 failure (a stage could not finish; the message says what to try). Unexpected errors are bugs:
they print a traceback and exit 1.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mlsim.cli_grammar import EXAMPLES, Formatter, add_shared, examples_epilog
from mlsim.cli_grammar import parse_sets as _parse_sets
from mlsim.errors import MlsimError, Problem, SceneError
from mlsim.units import unit_of

EXIT_OK, EXIT_FAILURE, EXIT_BAD_INPUT = 0, 1, 2

def _load(args):
    from mlsim.scene import load_scene

    return load_scene(args.scene, overrides=_parse_sets(args.set))


def _cache(args):
    from mlsim.pipeline import Cache

    return Cache(args.cache) if args.cache else Cache()


def _outputs(args, scene):
    if not args.outputs:
        return None
    from mlsim.stage import outputs

    OUTPUTS = outputs(scene.kind)
    names = tuple(o.strip() for part in args.outputs for o in part.split(",") if o.strip())
    bad = [n for n in names if n not in OUTPUTS]
    if bad:
        raise SceneError([Problem("--outputs", ",".join(bad), f"unknown output; choose from: {', '.join(OUTPUTS)}")])
    return names


def cmd_check(args) -> int:
    scene = _load(args)
    from fem.geometry import RodArray
    from mlsim.stage import outputs as outputs_of

    print(f"# {args.scene}: valid scene '{scene.name}' (hash {scene.content_hash()[:12]})")
    flat = scene.to_dotted()
    width = max(len(k) for k in flat)
    for key, value in flat.items():
        unit = unit_of(key)
        print(f"{key:<{width}} = {value!r:<24} {unit}".rstrip())
    if scene.kind != "ml_rod_array":
        print(f"\n# sensor kind {scene.kind!r}: outputs {', '.join(outputs_of(scene.kind))}")
        from mlsim.plausibility import warnings  # plausible but expensive (issue 39): the kind's own estimate

        for line in warnings(scene):
            print(f"warning: {line}")
        return EXIT_OK
    g = RodArray.from_sensor(scene.sensor)
    print("\n# derived")
    print(f"rods                     = {g.n_rods} ({scene.sensor.rows} x {scene.sensor.cols})")
    print(f"pitch                    = {g.pitch_x_m * 1e3:.4g} x {g.pitch_y_m * 1e3:.4g} mm")
    print(f"surface                  = {g.size_x_m * 1e3:.4g} x {g.size_y_m * 1e3:.4g} mm")
    print(f"body volume              = {g.volume_m3() * 1e9:.1f} mm^3")
    for name, vol in g.layer_volumes_m3().items():
        print(f"{name + ' volume':<24} = {vol * 1e9:.1f} mm^3")
    print(f"ML inner (emitting) area = {g.sheet_area_m2(g.core_depth_m) * 1e6:.1f} mm^2")
    if scene.load is not None:
        frames = scene.load.duration_s * scene.camera.fps
        print(f"load duration            = {scene.load.duration_s:.4g} s ({frames:.0f} frames at {scene.camera.fps:g} FPS)")
    from mlsim.plausibility import warnings  # plausible but expensive (issue 39)

    for line in warnings(scene):
        print(f"warning: {line}")
    print("\n# materials")
    for region in ("core", "ml_layer", "absorber"):
        m = scene.material(region)
        print(f"{region:<9} {m.name}: E = {m.young_modulus_pa.value:.4g} Pa [{m.young_modulus_pa.source}]; "
              f"nu = {m.poisson_ratio.value} [{m.poisson_ratio.source}]; "
              f"density = {m.density_kg_m3.value} kg/m^3 [{m.density_kg_m3.source}]")
    return EXIT_OK


def cmd_run(args, outputs=None, out_suffix: str = "") -> int:
    from mlsim import pipeline

    scene = _load(args)
    outputs = outputs or _outputs(args, scene)
    cache = _cache(args)
    from mlsim import run_budget  # the cost before the run, and its budget (issue 39)

    steps = pipeline.plan(scene, cache, outputs)
    estimate = run_budget.estimate(scene, steps, cache)
    if args.dry_run:  # the plan, then each stage's cost (one print: mlsim.dry_run)
        from mlsim.dry_run import print_plan

        return print_plan(scene, cache, outputs, args.scene, steps=steps, estimate=estimate)
    budget = getattr(args, "max_memory_gb", None), getattr(args, "max_frames", None), getattr(args, "over_budget", False)
    run_budget.enforce(estimate, *budget)  # mesh has no budget flags: the default memory budget
    out_dir = Path(args.out) if args.out else Path("out") / f"{scene.name}{out_suffix}"
    log = (lambda msg: None) if args.quiet else (lambda msg: print(msg, file=sys.stderr))
    log(estimate.headline())
    result = pipeline.run(scene, out_dir, cache, outputs, progress=not args.quiet, log=log, scene_path=str(args.scene))
    if not args.quiet:
        for name, files in result.files.items():
            for f in files:
                print(f"wrote {f}")
    return EXIT_OK


def cmd_mesh(args) -> int:
    code = cmd_run(args, outputs=("mesh",), out_suffix="_mesh")  # its own folder: a mesh run does not clobber a run's
    if code == EXIT_OK and not args.dry_run and not args.quiet:
        import json

        out_dir = Path(args.out) if args.out else Path("out") / f"{_load(args).name}_mesh"
        summary = json.loads((out_dir / "summary.json").read_text())
        m = summary["stages"]["mesh"]["summary"]
        q = m["quality"]
        print(f"mesh {m['mesh_hash'][:12]}: {m['n_tets']} tets, {m['n_points']} vertices ({m['n_nodes_quadratic']} quadratic nodes)")
        print(f"  dihedral angles {q['min_dihedral_deg']:.1f}-{q['max_dihedral_deg']:.1f} deg, "
              f"{q['slivers']} slivers (< {q['sliver_threshold_deg']:g} deg), min volume {q['min_volume_m3'] * 1e9:.3g} mm^3")
        print(f"  volume error {100 * m['volume_rel_error']:+.3f} %; layers "
              + ", ".join(f"{k} {100 * v:+.2f} %" for k, v in m["layer_volume_rel_error"].items()))
    return code


def cmd_accuracy(args) -> int:
    from mlsim.studies.accuracy import ERRORS, solve_accuracy

    if args.stage not in ("solve", "render"):
        raise SceneError([Problem("--stage", args.stage, "the accuracy studies are of the solve and the render stages; use --stage solve or render")])
    scene = _load(args)
    out_dir = Path(args.out) if args.out else Path("out") / f"{scene.name}_accuracy"
    if args.dry_run:
        from mlsim.dry_run import study_plan

        runs = ([f"path {n} spp" for n in args.spp] + [f"transport {n} spp" for n in args.transport_spp]
                + [f"deformed {n}x{n} direct samples" for n in args.direct_samples] + [f"reference: spectral path {args.reference_spp} spp"]
                if args.stage == "render" else
                [f"edge {e:g} mm, order {o}, {t}" for e in args.edges for o in args.orders for t in args.tiers])
        return study_plan(f"accuracy --stage {args.stage}", args.scene, out_dir, runs)
    if args.stage == "render":
        return _render_accuracy(args, scene, out_dir)
    reference = None
    if args.reference:
        parts = args.reference.split(",")
        if len(parts) != 3:
            raise SceneError([Problem("--reference", args.reference, "expected EDGE_MM,ORDER,TIER, e.g. 1.5,2,nonlinear")])
        reference = (float(parts[0]), int(parts[1]), parts[2].strip())
    log = (lambda msg: None) if args.quiet else (lambda msg: print(msg, file=sys.stderr))
    rows = solve_accuracy(scene, args.edges, tuple(args.orders), tuple(args.tiers), reference, out_dir, _cache(args),
                          progress=not args.quiet, log=log)
    print(f"{'edge mm':>8} {'order':>5} {'tier':>9} {'tets':>7} {'ms/frame':>9} {'pre s':>7} " + " ".join(f"{e:>20}" for e in ERRORS)
          + f" {'force est.':>10}")
    for r in rows:
        if r.failed:
            print(f"{r.edge_length_mm:>8g} {r.element_order:>5} {r.tier:>9}  failed: {r.failed}")
            continue
        errs = " ".join(f"{r.errors[e]:>19.3e}{'*' if r.errors.get(e + '_pareto') else ' '}" for e in ERRORS)
        est = f"{r.estimated_force_error:>10.2f}" if r.estimated_force_error == r.estimated_force_error else f"{'-':>10}"  # NaN: none
        print(f"{r.edge_length_mm:>8g} {r.element_order:>5} {r.tier:>9} {r.n_tets:>7} {r.per_frame_ms:>9.1f} {r.precompute_s:>7.1f} {errs} {est}"
              + ("   (reference)" if r.reference else ""))
    print(f"(* = on the Pareto front; force est. = the fast tiers' own estimate of their per-rod contact force error: from the "
          f"rods' bending, or with Cosserat rods from their ends turned with their tips, fem.rod_error)  wrote "
          f"{out_dir / 'accuracy_solve.csv'}, .json, .png")
    return EXIT_OK


def _render_accuracy(args, scene, out_dir: Path) -> int:
    from mlsim.studies.render_accuracy import RENDER_ERRORS, render_accuracy

    log = (lambda msg: None) if args.quiet else (lambda msg: print(msg, file=sys.stderr))
    rows, info = render_accuracy(scene, tuple(args.spp), tuple(args.transport_spp), args.reference_spp, args.frames,
                                 not args.no_spectral, out_dir, _cache(args), progress=not args.quiet, log=log,
                                 direct_per_sides=tuple(args.direct_samples))
    print(f"reference: spectral path tracing at {info['reference_spp']} spp on frames {info['frames']} "
          f"({info['reference_ms_per_frame'] / 1e3:.1f} s per frame); its own noise: "
          + ", ".join(f"{e} {info['reference_noise_' + e]:.2e}" for e in RENDER_ERRORS))
    print(f"{'tier':>14} {'spp':>5} {'spectral':>8} {'ms/frame':>10} {'pre s':>7} " + " ".join(f"{e:>15}" for e in RENDER_ERRORS))
    for r in rows:
        errs = " ".join(f"{r.errors[e]:>14.3e}{'*' if r.errors[e + '_pareto'] else ' '}" for e in RENDER_ERRORS)
        tier = f"{r.tier} {r.direct_per_side}x{r.direct_per_side}" if r.direct_per_side else r.tier
        print(f"{tier:>14} {r.spp:>5} {str(r.spectral):>8} {r.per_frame_ms:>10.2f} {r.precompute_s:>7.1f} {errs}")
    print(f"(* = on the Pareto front)  wrote {out_dir / 'accuracy_render.csv'}, .json, .png")
    return EXIT_OK


def _study(args, kind: str):
    """(scene, output directory (default out/<scene name>_<kind>), a log to stderr unless --quiet)."""
    scene = _load(args)
    out_dir = Path(args.out) if args.out else Path("out") / f"{scene.name}_{kind}"
    return scene, out_dir, (lambda msg: None) if args.quiet else (lambda msg: print(msg, file=sys.stderr))


def cmd_direction(args) -> int:
    from dllm.direction import SIGN_CONVENTION
    from mlsim.studies.direction import direction_study, summary

    scene, out_dir, log = _study(args, "direction")
    if args.dry_run:
        from mlsim.dry_run import study_plan

        return study_plan("direction", args.scene, out_dir, [f"push towards {a:g} deg" for a in args.angles], scene, _cache(args), ("dllm",))
    rows = direction_study(scene, args.angles, out_dir, _cache(args), progress=not args.quiet, log=log)
    print(f"sign convention: {SIGN_CONVENTION}")
    print(f"{'applied':>8} {'approach':>8} {'measured':>9} {'error':>7} {'all taxels':>10} {'events':>6} {'push':>5} {'samples':>7}  taxels")
    for r in rows:
        print(f"{r.applied_deg:>8g} {r.approach_deg:>8g} {r.measured_deg:>9.1f} {r.error_deg:>7.1f} {r.error_all_deg:>10.1f} {r.events:>6} "
              f"{r.push_events:>5} {r.samples:>7}  {' '.join(map(str, r.taxels))}")
    figures = summary(rows)
    mae, mae_all = figures["mean_abs_error_deg"], figures["mean_abs_error_all_taxels_deg"]
    n = len(rows) - len(figures["episodes_without_events"])
    print(f"mean absolute error {mae:.1f} deg over {n} directions, pushed taxels in the push frames "
          f"({mae_all:.1f} deg over every firing taxel and event frame; SPEC 1.5: within a few degrees on the real sensor)"
          if mae is not None else "no direction gave events")
    print(f"wrote {out_dir / 'direction.csv'}, .json, .png")
    return EXIT_OK


def cmd_ambient(args) -> int:
    from mlsim.studies.ambient import ambient_study

    scene, out_dir, log = _study(args, "ambient")
    if args.dry_run:
        from mlsim.dry_run import study_plan
        from mlsim.studies.ambient import setting_scenes

        runs = [f"{name}: interaction and idle episodes, then {len(args.alphas)} x {len(args.betas)} thresholds" for name in setting_scenes(scene)]
        return study_plan("ambient", args.scene, out_dir, runs, scene, _cache(args), ("camera", "calibration"))
    rows, rec = ambient_study(scene, alphas=tuple(args.alphas), betas=tuple(args.betas), out_dir=out_dir, cache=_cache(args),
                              progress=not args.quiet, log=log)
    print(f"{'setting':36} {'alpha':>6} {'beta':>5} {'detection':>9} {'false':>6} {'taxels':>6}")
    for r in rows:
        mark = " <" if (r.alpha, r.beta) == (rec.get("alpha"), rec.get("beta")) else ""
        print(f"{r.setting:36} {r.alpha:>6g} {r.beta:>5g} {r.detection:>9.3f} {r.false_rate:>6.3f} {r.taxel_detection:>6.3f}{mark}")
    if rec.get("false_triggers_at_any_threshold"):
        print("false triggers at every threshold of the grid (the detector fires until it recovers): "
              + "; ".join(rec["false_triggers_at_any_threshold"]))
    if rec.get("alpha") is None:
        print(f"no recommendation: {rec['why']}")
    else:
        print(f"recommended: alpha {rec['alpha']:g}, beta {rec['beta']:g} ({rec['why']}; worst detection {rec['worst_detection']:.3f})")
        for name, v in rec["per_setting"].items():
            print(f"  {name}: detection {v['detection']:.3f}, false triggers {v['false_rate']:.3f} per frame, taxels {v['taxel_detection']:.3f}")
    print(f"wrote {out_dir / 'ambient_study.csv'}, .json and a heatmap per setting")
    return EXIT_OK


def cmd_dataset(args) -> int:
    from mlsim.dataset.generate import generate
    from mlsim.dataset.spec import load_dataset_spec
    from mlsim.dataset.store import DatasetMismatch

    overrides = _parse_sets(args.set)
    nested = [k for k in overrides if "." in k]
    if nested:
        raise SceneError([Problem("--set", ",".join(nested), "a dataset spec's --set changes its top-level fields (samples_per_action, people, "
                                  "seed, store_frames, ...); change [interaction] in the spec file, or the base scene")])
    overrides |= {k: v for k, v in (("samples_per_action", args.samples_per_action), ("people", args.people), ("seed", args.seed)) if v is not None}
    spec, base = load_dataset_spec(args.scene, overrides)
    if args.executor == "local" and args.address:
        raise SceneError([Problem("--address", args.address, "only with --executor ray")])
    out = Path(args.out) if args.out else Path("out") / spec.name
    if args.dry_run:
        from mlsim.dry_run import dataset_plan

        return dataset_plan(spec, base, out, args.workers, args.executor)
    log = (lambda msg: None) if args.quiet else (lambda msg: print(msg, file=sys.stderr))
    try:
        summary = generate(spec, base, out, workers=args.workers, executor=args.executor, address=args.address, cache_dir=args.cache,
                           progress=not args.quiet, log=log)
    except DatasetMismatch as exc:
        raise SceneError([Problem("--out", str(out), str(exc))]) from None
    except KeyboardInterrupt:
        print(f"interrupted: the finished episodes are stored in {out}; rerun the same command to complete the dataset", file=sys.stderr)
        return 130
    print(f"{summary['episodes_stored']}/{summary['episodes_planned']} episodes in {out} "
          f"({summary['episodes_run_now']} now in {summary['episodes_wall_s']} s, {summary['episodes_per_s']} episodes/s; "
          f"precompute {summary['precompute_s']} s)")
    if summary.get("episodes_failed"):
        # a dataset with holes is not a success for a script that trains on it: exit 1 with the list
        from mlsim.dataset.generate import failures_line

        print(f"{failures_line(summary['failures'])}; listed in {out / 'failures.json'}; rerun the same command to retry only them",
              file=sys.stderr)
        return EXIT_FAILURE
    return EXIT_OK


def cmd_sweep(args) -> int:
    from mlsim.sweep.run import DEFAULT_DIRECTION, read_load, sweep
    from mlsim.sweep.variants import parse_vary

    scene = _load(args)
    varies = parse_vary(args.vary)
    if not varies:
        raise SceneError([Problem("--vary", None, "give at least one field to vary, e.g. --vary sensor.rod.height_mm=6,7.5,9,10.5,12")])
    if args.executor == "local" and args.address:
        raise SceneError([Problem("--address", args.address, "only with --executor ray")])
    from mlsim.sweep.run import METRICS, check_metrics

    wanted = tuple(m.strip() for part in args.metrics or [",".join(METRICS)] for m in part.split(",") if m.strip())
    check_metrics(wanted)  # before a dry run too: it would price the known ones and say nothing of the rest
    loads = [read_load(p) for p in args.load] if args.load else None
    direction = read_load(args.direction_scene or DEFAULT_DIRECTION, "--direction-scene") if "direction" in wanted else None
    out = Path(args.out) if args.out else Path("out") / f"{scene.name}_sweep"
    if args.dry_run:
        from mlsim.dry_run import sweep_plan
        from mlsim.sweep.variants import variants

        return sweep_plan(scene, variants(scene, varies, "zip" if args.zip else "grid"), out, loads, wanted, args.workers, cache=_cache(args),
                          direction=direction, angles=tuple(args.angles), escalate_to=None if args.escalate_tier == "none" else args.escalate_tier)
    log = (lambda msg: None) if args.quiet else (lambda msg: print(msg, file=sys.stderr))
    try:
        summary = sweep(scene, varies, out, mode="zip" if args.zip else "grid", loads=loads, direction=direction, angles=tuple(args.angles),
                        wanted=wanted, workers=args.workers, executor=args.executor, address=args.address, cache_dir=args.cache,
                        progress=not args.quiet, log=log, escalate_to=None if args.escalate_tier == "none" else args.escalate_tier)
    except KeyboardInterrupt:
        print(f"interrupted: the finished variants are stored in {out}; rerun the same command to complete the sweep", file=sys.stderr)
        return 130
    print((out / "sweep.md").read_text())
    print(f"{summary['stored']}/{summary['variants']} variants in {out} ({summary['run_now']} now in {summary['wall_s']} s); "
          f"wrote {', '.join(Path(f).name for f in summary['files'])}")
    return EXIT_OK


def cmd_detect(args) -> int:
    from mlsim.detect import run_command
    from mlsim.scene import Scene, load_scene

    sets = _parse_sets(args.set)
    return run_command(args, load_scene(args.scene, overrides=sets) if args.scene else Scene().with_values(sets))


def cmd_calibrate(args) -> int:
    from mlsim.scene import load_scene
    from mlsim.sensor_calibration import calibrate_sensor, plan_calibration

    sets = _parse_sets(args.set)
    out = Path(args.out) if args.out else Path("out") / f"{load_scene(args.scene, overrides=sets).name}_calibrate"
    if args.dry_run:
        print(plan_calibration(args.photo, args.scene, out, idle=args.idle, press=args.press, force_n=args.force_n, overrides=sets))
        return EXIT_OK
    log = (lambda msg: None) if args.quiet else (lambda msg: print(msg, file=sys.stderr))
    fit = calibrate_sensor(args.photo, args.scene, out, idle=args.idle, press=args.press, force_n=args.force_n,
                           cache=_cache(args), log=log, overrides=sets)
    print(f"focal length {fit['focal_length_mm']:.4f} +- {fit['focal_length_sigma_mm']:.2g} mm; wrote {out / 'sensor.toml'}")
    return EXIT_OK


def build_parser() -> argparse.ArgumentParser:
    from mlsim import __version__

    parser = argparse.ArgumentParser(prog="mlsim", description="Simulate the mechanoluminescent visuotactile sensor and its siblings.",
                                     epilog="examples:\n" + "\n".join(f"  {e[0]}" for e in EXAMPLES.values()), formatter_class=Formatter)
    parser.add_argument("--version", action="version", version=f"mlsim {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="VERB")

    def verb(name: str, help: str, func, out_default: str = "", scene_help: str = "scene file (TOML), e.g. scenes/mavig_default.toml",
             metavar: str = "SCENE", dest: str = "scene", **shared):
        p = sub.add_parser(name, help=help, description=help, epilog=examples_epilog(name), formatter_class=Formatter)
        p.add_argument(dest, metavar=metavar, help=scene_help)
        add_shared(p, name, out_default=out_default, **shared)
        p.set_defaults(func=func)
        return p

    p = verb("run", "run the stages the scene's outputs need", cmd_run, "out/<scene name>")
    p.add_argument("--outputs", action="append", help="products to write instead of the scene's (comma-separated)")
    p.add_argument("--max-memory-gb", type=float, metavar="GB", help="refuse a run expected to need more (default: half the machine's memory)")
    p.add_argument("--max-frames", type=int, metavar="N", help="refuse a run of more frames")
    p.add_argument("--over-budget", action="store_true", help="run even past --max-memory-gb / --max-frames")

    verb("check", "validate a scene and print it resolved, with units", cmd_check)
    verb("mesh", "build the tet mesh, report its quality, write VTU", cmd_mesh, "out/<scene name>_mesh")

    p = verb("accuracy", "error against run time of a stage's fidelity knobs (table, CSV, log-log plot)", cmd_accuracy,
             "out/<scene name>_accuracy")
    p.add_argument("--stage", default="solve", choices=["solve", "render"], help="the stage to study")
    p.add_argument("--edges", type=float, nargs="+", default=[2.5, 2.0, 1.5], metavar="MM", help="mesh edge lengths")
    p.add_argument("--orders", type=int, nargs="+", default=[1, 2], choices=[1, 2], help="element orders")
    p.add_argument("--tiers", nargs="+", default=["reduced", "linear", "nonlinear"], choices=["reduced", "linear", "nonlinear"])
    p.add_argument("--reference", help="EDGE_MM,ORDER,TIER (default: the finest edge, order 2, nonlinear)")
    p.add_argument("--spp", type=int, nargs="+", default=[1, 4, 16, 64], help="render: path tier samples per pixel")
    p.add_argument("--transport-spp", type=int, nargs="+", default=[16, 64], help="render: transport tier trace samples per pixel")
    p.add_argument("--reference-spp", type=int, default=256, help="render: the spectral reference's samples per pixel")
    p.add_argument("--direct-samples", type=int, nargs="*", default=[1, 2, 3], metavar="N",
                   help="render: the deformed tier's direct light at N x N samples per pixel (none: skip the tier)")
    p.add_argument("--frames", type=int, default=4, help="render: how many glowing frames (evenly spread) are compared")
    p.add_argument("--no-spectral", action="store_true", help="render: skip the path tier's spectral renders")

    p = verb("direction", "the DLLM's angle against the applied push direction (SPEC 1.5 direction test)", cmd_direction,
             "out/<scene name>_direction")
    p.add_argument("--angles", type=float, nargs="+", default=[15.0 * k for k in range(24)], metavar="DEG",
                   help="applied directions (default: the full circle in 15 deg steps; SPEC 1.5's bench test: 0 15 ... 90)")

    p = verb("ambient", "DLLM thresholds under ambient light: detection and false triggers per setting and (alpha, beta)", cmd_ambient,
             "out/<scene name>_ambient")
    p.add_argument("--alphas", type=float, nargs="+", default=[1.01, 1.02, 1.05, 1.1, 1.2], help="global gate factors")
    p.add_argument("--betas", type=float, nargs="+", default=[1.1, 1.3, 1.5, 2.0], help="taxel gate factors")

    p = verb("dataset", "generate a synthetic interaction dataset (episodes in parallel; resumable; Zarr)", cmd_dataset,
             "out/<spec name>; a rerun into it resumes", scene_help="dataset spec (TOML), e.g. scenes/interactions/small.toml", metavar="SPEC")
    p.add_argument("--executor", choices=["local", "ray"], default="local", help="local process pool, or Ray (pip install 'mlsim[ray]')")
    p.add_argument("--address", help="Ray cluster address, e.g. 127.0.0.1:6379 (default: start a local Ray)")
    p.add_argument("--samples-per-action", type=int, help="override the spec's samples_per_action (same as --set samples_per_action=N)")
    p.add_argument("--people", type=int, help="override the spec's people")
    p.add_argument("--seed", type=int, help="override the spec's seed")

    p = verb("sweep", "compare rod geometries and materials: brightness, sensitivity, direction, separation, tear risk per variant", cmd_sweep,
             "out/<scene name>_sweep; a rerun into it resumes",
             workers_help="variants in parallel, one thread each (default: the CPU count; each holds its sensor's factorised stiffness, "
                          "about 1 GB on the default mesh)")
    p.add_argument("--vary", action="append", metavar="PATH=V1,V2,...", help="a field and its values, e.g. sensor.rod.height_mm=6,7.5,9,10.5,12 "
                   "or sensor.materials.core=SC37,PDMS,DS30 (repeat for more fields)")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--grid", action="store_true", help="every combination of the varied values (default)")
    mode.add_argument("--zip", action="store_true", help="the i-th values of every --vary together")
    p.add_argument("--load", action="append", metavar="SCENE", help="a scene file whose [load] every variant gets (repeat; default: "
                   "scenes/press.toml and scenes/swipe.toml)")
    p.add_argument("--direction-scene", metavar="SCENE", help="the direction study's load (default scenes/direction_test.toml)")
    p.add_argument("--escalate-tier", choices=["nonlinear", "none"], default="nonlinear",
                   help="the tier that solves a load the variant's fast tier refuses as beyond its model (rods near buckling, "
                        "contact points past small strain); the report's tiers column says which answered (default nonlinear, with "
                        "backward-Euler dynamics: the swipe over 10.5 mm rods took 47 min on 2 shared cores; none: record the refusal)")
    p.add_argument("--angles", type=float, nargs="+", default=[0.0, 45.0, 90.0], metavar="DEG", help="the direction study's push directions")
    p.add_argument("--metrics", action="append", default=None, metavar="LIST",
                   help="what to measure (comma-separated; default all): brightness, tear, separation, direction")
    p.add_argument("--executor", choices=["local", "ray"], default="local", help="local process pool, or Ray (pip install 'mlsim[ray]')")
    p.add_argument("--address", help="Ray cluster address (default: start a local Ray)")

    # real sensors (issue 41): a recording through the DLLM (and the CNN); a scene overlay fitted to recordings
    p = verb("detect", "a recording (video or folder of frames) through the DLLM (and the CNN): the CSVs, heatmap and events of a simulated run",
             cmd_detect, "out/detect_<recording name>", metavar="RECORDING", dest="recording",
             scene_help="a video (MP4, AVI, MKV, MOV) or a folder of PNG/JPEG frames; its first second idle")
    p.add_argument("--calibration", required=True, metavar="PHOTO",
                   help="the calibration photo (the sensor without its absorber, lit; SPEC 1.6), same camera and resolution")
    p.add_argument("--scene", help="the sensor's scene (TOML): its grid, DLLM thresholds and optics (default: SPEC 1.6's 5 x 5, defaults)")
    p.add_argument("--idle", metavar="VIDEO", help="an idle recording for the thresholds (default: the recording's first second)")
    p.add_argument("--fps", type=float, help="frame rate of the recording (default: the video's, else the scene's camera)")
    p.add_argument("--model", help="a classifier of 'mlsim train' (interaction_8class.pt): also write classify.csv")

    p = verb("calibrate", "a scene overlay for a real sensor from its calibration photo (the camera's view), idle video (dark noise) and a "
                          "press of known force (ML brightness)", cmd_calibrate, "out/<scene name>_calibrate",
             scene_help="the sensor's scene (TOML): the rods' layout and the camera distance, e.g. scenes/mavig_default.toml")
    p.add_argument("--photo", required=True, help="the calibration photo (the sensor without its absorber, lit; SPEC 1.6)")
    p.add_argument("--idle", metavar="VIDEO", help="an idle recording at the scene's camera settings: black level and read noise")
    p.add_argument("--press", metavar="VIDEO", help="a recorded press (its first second idle) of the scene's [load]: the ML brightness")
    p.add_argument("--force-n", type=float, metavar="F", help="the press's force (N), set on the [load]'s force-controlled press")
    try:
        from mlsim.studies.classifier_cli import add_parsers
    except ImportError:
        pass
    else:
        add_parsers(sub)
        from mlsim.studies.anyskin_cli import add_parsers as add_anyskin_parsers  # mlsim anyskin-train (issue 19)

        add_anyskin_parsers(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse exits 2 on bad arguments, which matches our convention
        return int(exc.code or 0)
    try:
        return args.func(args)
    except SceneError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except MlsimError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    except KeyboardInterrupt:
        print("interrupted: finished stages are cached; rerun to resume", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
