"""The layers of the house (issue 17): no module imports from a layer above its own, and no import
circle, counting every import statement (module level and inside functions: a lazy import is still
a dependency). Read with the standard library's ``ast``; nothing is imported.

Layers, lowest first:

0. base: errors, scene types, the stage registry, atomic I/O, plots, materials and their laws;
1. stages: the physics and the detector, each stage declared next to its code (``fem``,
   ``mlsim.emission``, ``mlsim.render``, ``mlsim.camera``, ``dllm``, ``classifiers``), and the sensor
   kinds that register them (``mlsim.ml_rod_array``);
2. orchestration: the planner and cache, the command line, the two job drivers (``mlsim.dataset``,
   ``mlsim.sweep``) and the studies that run the pipeline (``mlsim.studies``).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("mlsim", "fem", "dllm", "classifiers", "other_sensors")
BASE = ("mlsim", "mlsim.errors", "mlsim.io", "mlsim.stage", "mlsim.scene", "mlsim.plausibility", "mlsim.cost_model", "mlsim.materials", "mlsim.spectra",
        "mlsim.plots", "mlsim.units", "fem.materials", "fem.materials.linear_elastic", "fem.materials.neo_hookean", "fem.materials.shore_hardness")
ORCHESTRATION = ("mlsim.pipeline", "mlsim.cli", "mlsim.cli_grammar", "mlsim.dry_run", "mlsim.run_budget", "mlsim.docgen", "mlsim.__main__", "mlsim.dataset",
                 "mlsim.sweep", "mlsim.studies", "mlsim.detect", "mlsim.sensor_calibration", "mlsim.press_brightness")
#: the stage packages: the physics and the detector, no driver of the pipeline
STAGE_PACKAGES = ("fem", "mlsim.emission", "mlsim.render", "mlsim.camera", "dllm", "classifiers", "other_sensors")


def layer(module: str) -> int:
    if any(module == p or module.startswith(p + ".") for p in ORCHESTRATION):
        return 2
    return 0 if module in BASE else 1


def modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for f in (ROOT / pkg).rglob("*.py"):
            parts = list(f.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = f
    return out


def import_graph() -> dict[str, set[str]]:
    """module -> the project's modules it imports (``from pkg import sub`` counts as the submodule)."""
    mods = modules()

    def resolve(name: str) -> str | None:
        while name and name not in mods:
            name = name.rsplit(".", 1)[0] if "." in name else ""
        return name or None

    graph: dict[str, set[str]] = {m: set() for m in mods}
    for m, path in mods.items():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    pkg = m if path.name == "__init__.py" else m.rsplit(".", 1)[0]
                    for _ in range(node.level - 1):
                        pkg = pkg.rsplit(".", 1)[0]
                    base = f"{pkg}.{base}" if base else pkg
                names = [f"{base}.{a.name}" if f"{base}.{a.name}" in mods else base for a in node.names]
            else:
                continue
            for n in names:
                r = resolve(n)
                if r is not None and r != m:
                    graph[m].add(r)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_module_imports_from_a_layer_above_its_own():
    graph = import_graph()
    upward = [f"{m} (layer {layer(m)}) imports {d} (layer {layer(d)})" for m in sorted(graph) for d in sorted(graph[m]) if layer(d) > layer(m)]
    assert upward == []


def test_no_study_in_a_stage_package():
    """A module that drives the pipeline (imports the planner, the CLI, datasets or sweeps) is a study:
    it belongs to the orchestration layer's folders (``mlsim.studies``, or the job drivers
    ``mlsim.dataset`` and ``mlsim.sweep``), not to a stage's package, where only its physics stays."""
    graph = import_graph()
    drivers = {m for m, deps in graph.items() if any(layer(d) == 2 for d in deps) or layer(m) == 2}
    in_stages = sorted(m for m in drivers if any(m == p or m.startswith(p + ".") for p in STAGE_PACKAGES))
    assert in_stages == []


def test_there_is_no_import_circle():
    assert cycles(import_graph()) == []


def test_the_checks_see_what_they_should():
    """The graph and the checks on a known case: the planner imports the registry, a circle is found."""
    graph = import_graph()
    assert "mlsim.stage" in graph["mlsim.pipeline"] and layer("mlsim.pipeline") == 2 and layer("mlsim.stage") == 0
    assert "fem.episode" in graph["fem.finite_strain"]
    assert "dllm.direction" in graph["mlsim.studies.direction"] and layer("mlsim.studies.direction") == 2 and layer("dllm.direction") == 1
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
