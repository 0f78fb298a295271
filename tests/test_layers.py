"""The package's layering (docs/architecture.md) holds: imports point down, and no module imports itself back.

Every ``import`` and ``from ... import`` of ``drem_maniskill`` in the package's source is read
with ``ast``, function-local ones included (they keep a cycle from failing at import time, not
from being a cycle).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import drem_maniskill

PACKAGE = Path(drem_maniskill.__file__).parent

# Top-level part of the package -> its layer. A module may import a lower layer, or its own part.
LAYERS = {
    "version": 0, "utils": 0,
    "drem": 1, "baselines": 1,
    "envs": 2,
    "experts": 3,
    "rl": 4,
    "evaluate": 5,  # judging a reward: check-reward trains SAC on it
    "pipeline": 6,  # building a reward: a build examines it, policy rounds train SAC on it
    "demo": 7, "launcher": 7,
    "cli": 8, "__init__": 8,
}


def _module_name(path: Path) -> str:
    rel = path.relative_to(PACKAGE.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _is_module(name: str) -> bool:
    base = PACKAGE.parent.joinpath(*name.split("."))
    return base.with_suffix(".py").exists() or (base / "__init__.py").exists()


def package_imports() -> dict:
    """Module name -> the package modules it imports (``from pkg import submodule`` counts as the submodule)."""
    graph = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        name = _module_name(path)
        targets = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets |= {a.name for a in node.names if a.name.split(".")[0] == "drem_maniskill"}
            elif (isinstance(node, ast.ImportFrom) and node.level == 0
                  and (node.module or "").split(".")[0] == "drem_maniskill"):
                for alias in node.names:
                    sub = f"{node.module}.{alias.name}"
                    targets.add(sub if _is_module(sub) else node.module)
            elif isinstance(node, ast.ImportFrom) and node.level:
                raise AssertionError(f"{path}: relative import; write drem_maniskill.... so this test can read it")
        graph[name] = targets - {name}
    return graph


def part_of(module: str) -> str:
    """The top-level part of a module name (``drem_maniskill`` itself is ``__init__``)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def test_every_part_has_a_layer():
    parts = {part_of(m) for m in package_imports()}
    assert parts <= set(LAYERS), f"give {sorted(parts - set(LAYERS))} a layer here and in docs/architecture.md"


def upward_imports(graph: dict) -> list:
    """The imports of ``graph`` into another part of the same or a higher layer."""
    wrong = []
    for module, targets in graph.items():
        src = part_of(module)
        for target in targets:
            dst = part_of(target)
            if dst != src and LAYERS[dst] >= LAYERS[src]:
                wrong.append(f"{module} (layer {LAYERS[src]}) imports {target} (layer {LAYERS[dst]})")
    return sorted(wrong)


def test_imports_point_down():
    wrong = upward_imports(package_imports())
    assert not wrong, "imports against the layering:\n" + "\n".join(wrong)


def find_cycle(graph: dict):
    """One import cycle of ``graph`` as a list of modules, or None."""
    state, stack = {}, []

    def visit(node):
        state[node] = "open"
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == "open":
                return stack[stack.index(nxt):] + [nxt]
            if nxt not in state:
                found = visit(nxt)
                if found:
                    return found
        stack.pop()
        state[node] = "done"
        return None

    for node in sorted(graph):
        if node not in state:
            found = visit(node)
            if found:
                return found
    return None


def test_no_import_cycle():
    cycle = find_cycle(package_imports())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_the_checks_catch_what_they_are_for():
    """An upward import, a same-layer import between parts and a cycle, planted in a copy of the graph, are found."""
    graph = {k: set(v) for k, v in package_imports().items()}
    graph["drem_maniskill.utils.cameras"].add("drem_maniskill.envs.adapter")  # up, and a cycle through adapter
    graph["drem_maniskill.drem.reward"].add("drem_maniskill.baselines.vice")  # sideways
    graph["drem_maniskill.rl.train_policy"].add("drem_maniskill.evaluate.examine")  # up: rl is below judging
    wrong = upward_imports(graph)
    for planted in ("drem_maniskill.utils.cameras (layer 0) imports drem_maniskill.envs.adapter",
                    "drem_maniskill.drem.reward (layer 1) imports drem_maniskill.baselines.vice",
                    "drem_maniskill.rl.train_policy (layer 4) imports drem_maniskill.evaluate.examine"):
        assert any(w.startswith(planted) for w in wrong), planted
    cycle = find_cycle(graph)
    assert cycle is not None and "drem_maniskill.utils.cameras" in cycle
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


def judging_imports_of_building(graph: dict) -> list:
    """The imports of ``graph`` from a module of ``drem_maniskill.evaluate`` into ``drem_maniskill.pipeline``."""
    return sorted(f"{module} imports {target}" for module, targets in graph.items() for target in targets
                  if part_of(module) == "evaluate" and part_of(target) == "pipeline")


def test_judging_never_imports_building():
    """A reward is judged by what it pays, whatever built it: ``evaluate`` reads checkpoints, never the builder's code
    (function-local imports count)."""
    graph = package_imports()
    wrong = judging_imports_of_building(graph)
    assert not wrong, "evaluate imports pipeline (move the piece it needs below both):\n" + "\n".join(wrong)
    graph["drem_maniskill.evaluate.examine"].add("drem_maniskill.pipeline.tree.tree_file")
    assert judging_imports_of_building(graph) == [
        "drem_maniskill.evaluate.examine imports drem_maniskill.pipeline.tree.tree_file"]


def building_imports_of_rl(graph: dict) -> list:
    """The modules of ``drem_maniskill.pipeline`` in ``graph`` that import ``drem_maniskill.rl``."""
    return sorted(module for module, targets in graph.items()
                  if part_of(module) == "pipeline" and any(part_of(t) == "rl" for t in targets))


def test_building_reaches_sac_in_one_place():
    """Of building, only the policy rounds reach SAC (those of a build train it; those during a run register their
    reward in its table); the rest of a build reaches it through them."""
    graph = package_imports()
    rounds = ["drem_maniskill.pipeline.online_rounds", "drem_maniskill.pipeline.policy_rounds"]
    assert building_imports_of_rl(graph) == rounds
    graph["drem_maniskill.pipeline.dataset"].add("drem_maniskill.rl.config")
    assert building_imports_of_rl(graph) == ["drem_maniskill.pipeline.dataset", *rounds]


@pytest.mark.parametrize("call", ["update_render(update_sensors=True"])
def test_one_place_renders_the_cameras(call):
    places = [str(p.relative_to(PACKAGE)) for p in PACKAGE.rglob("*.py") if call in p.read_text()]
    assert places == ["utils/cameras.py"], places
