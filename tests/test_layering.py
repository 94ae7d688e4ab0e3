"""The import layering of odofuse, enforced: no circle, teaching apart, the pipeline one way.

:data:`LAYERS` is the one place that defines the layering. Every module of ``odofuse`` is
parsed with :mod:`ast` (module-level imports, imports inside functions, and
``importlib.import_module("odofuse...")`` calls) and must

* belong to a layer of :data:`LAYERS` (a new module must be added there),
* import only modules of its own layer or a lower one (a layer marked ``independent`` also
  forbids imports between its own modules),
* never import ``odofuse.teaching`` unless it is in ``odofuse.teaching`` or is ``odofuse.cli``
  (which wires the teaching subcommands),

and the import graph among odofuse modules has no cycle.
"""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "odofuse"

#: The layers, lowest first: (layer name, independent, module or sub-package names).
#: A sub-package name (``odofuse.io``) covers all its modules. ``independent``: the modules of
#: the layer must not import each other.
LAYERS: tuple[tuple[str, bool, tuple[str, ...]], ...] = (
    # Data types and algebra every layer uses; they import nothing of odofuse above them.
    (
        "base",
        False,
        (
            "odofuse",
            "odofuse.errors",
            "odofuse.se2",
            "odofuse.testing",
            "odofuse.trajectory",
            "odofuse.plugins",
            # the status package (every check, by role): its catalog and the findings type
            "odofuse.status",
            "odofuse.status.findings",
            "odofuse.chi2",
        ),
    ),
    # What the robot's readings mean (drive kinematics, encoder units): needed by io to turn
    # wheels.csv into drive inputs and by config to validate the geometry.
    ("robot", False, ("odofuse.drives", "odofuse.encoders")),
    ("io", False, ("odofuse.io",)),
    # The option declarations (a package: common, run, sensors, filters, graph, estimators) and
    # the config they validate; the graph estimators' GraphOptions live here, not in graph/.
    (
        "config",
        False,
        ("odofuse.options", "odofuse.declarations", "odofuse.config", "odofuse.log_defaults"),
    ),
    # Packages by role: motion (integrators, noise, model), measurements (base, absolute, gyro,
    # landmarks, registry).
    ("models", False, ("odofuse.motion", "odofuse.measurements", "odofuse.frames")),
    # the in-run checks of the status package beside the estimators that feed them
    (
        "estimators",
        False,
        (
            "odofuse.estimators",
            "odofuse.status.streaming",
            "odofuse.status.mde",
            "odofuse.status.slip",
            "odofuse.status.monitors",
            "odofuse.status.drift",
            "odofuse.status.pose_checks",
            "odofuse.status.latency",
            "odofuse.status.graph_checks",
        ),
    ),
    (
        "results",
        True,
        ("odofuse.evaluation", "odofuse.outputs", "odofuse.outputs_ros", "odofuse.plotting"),
    ),
    (
        "run folder",
        False,
        ("odofuse.rundir", "odofuse.status.cross_check", "odofuse.status.geometry", "odofuse.tune"),
    ),
    ("fleet", False, ("odofuse.batch",)),
    # odofuse live (issue 27): rmw (wire format), transport, messages, component, run.
    ("live", False, ("odofuse.live",)),
    ("command line", False, ("odofuse.cli", "odofuse.__main__")),
    # May import anything; imported only by itself and by odofuse.cli (see TEACHING_USERS).
    ("teaching", False, ("odofuse.teaching",)),
)
TEACHING = "odofuse.teaching"
TEACHING_USERS = ("odofuse.cli",)


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def all_modules() -> dict[str, Path]:
    return {module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


MODULES = all_modules()


def _target(name: str) -> str | None:
    """The odofuse module an imported dotted name refers to (a module or its package)."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def imports_of(name: str, path: Path) -> set[str]:
    """The odofuse modules that module ``name`` imports anywhere in its file."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    # ``if TYPE_CHECKING:`` imports never run: they name a type for annotations only.
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.If)
            and isinstance(node.test, ast.Name)
            and node.test.id == "TYPE_CHECKING"
        ):
            node.body = []
    is_pkg = path.name == "__init__.py"
    found: set[str | None] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(_target(a.name) for a in node.names if a.name.startswith("odofuse"))
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".")[: len(name.split(".")) - node.level + is_pkg]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            if not mod.startswith("odofuse"):
                continue
            for alias in node.names:
                # ``from odofuse import se2`` imports the module odofuse.se2.
                found.add(_target(f"{mod}.{alias.name}"))
        elif (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and node.func.attr == "import_module"
            and node.args
            and isinstance(node.args[0], ast.Constant)
            and isinstance(node.args[0].value, str)
            and node.args[0].value.startswith("odofuse")
        ):
            found.add(_target(node.args[0].value))
    found.discard(None)
    found.discard(name)
    return found  # type: ignore[return-value]


@functools.cache
def graph() -> dict[str, set[str]]:
    """Module -> the odofuse modules it imports (parsed once, when a test first asks: not at
    collection, which every pytest-xdist worker does)."""
    return {name: imports_of(name, path) for name, path in MODULES.items()}


def layer_of(name: str) -> tuple[int, str, bool] | None:
    """(rank, entry, independent) of the longest LAYERS entry covering module ``name``."""
    best = None
    for rank, (_, independent, entries) in enumerate(LAYERS):
        for entry in entries:
            if name == entry or (name.startswith(entry + ".") and entry != "odofuse"):
                if best is None or len(entry) > len(best[1]):
                    best = (rank, entry, independent)
    return best


def test_every_module_is_in_the_layer_table():
    unknown = [
        f"{name} ({path.relative_to(PACKAGE.parent)})"
        for name, path in MODULES.items()
        if layer_of(name) is None
    ]
    assert not unknown, (
        f"modules not in the layer table: {', '.join(unknown)}. Add each to the layer it belongs "
        "to in LAYERS of tests/test_layering.py (a module may import only its own layer or lower "
        "ones)."
    )


def test_every_layer_table_entry_exists():
    stale = [e for _, _, entries in LAYERS for e in entries if e not in MODULES]
    assert not stale, f"LAYERS of tests/test_layering.py names missing modules: {stale}"


def test_no_import_cycle():
    # Iterative depth-first search; a back edge to a module on the stack closes a cycle.
    state: dict[str, int] = {}  # 1 = on the stack, 2 = done
    cycles = []
    for root in sorted(graph()):
        if root in state:
            continue
        stack = [(root, iter(sorted(graph()[root])))]
        path = [root]
        state[root] = 1
        while stack:
            node, children = stack[-1]
            child = next(children, None)
            if child is None:
                state[node] = 2
                stack.pop()
                path.pop()
            elif state.get(child) == 1:
                cycles.append(" -> ".join(path[path.index(child) :] + [child]))
            elif child not in state:
                state[child] = 1
                path.append(child)
                stack.append((child, iter(sorted(graph()[child]))))
    assert not cycles, "import cycles among odofuse modules:\n" + "\n".join(cycles)


def test_only_the_cli_imports_teaching():
    bad = [
        f"{name} imports {dep}"
        for name, deps in sorted(graph().items())
        for dep in sorted(deps)
        if (dep == TEACHING or dep.startswith(TEACHING + "."))
        and not (name == TEACHING or name.startswith(TEACHING + "."))
        and name not in TEACHING_USERS
    ]
    assert not bad, "the library must not import odofuse.teaching:\n" + "\n".join(bad)


def test_imports_follow_the_pipeline():
    bad = []
    for name, deps in sorted(graph().items()):
        here = layer_of(name)
        if here is None:
            continue  # reported by test_every_module_is_in_the_layer_table
        for dep in sorted(deps):
            there = layer_of(dep)
            if there is None or (name in TEACHING_USERS and there[1] == TEACHING):
                continue
            if there[0] > here[0]:
                bad.append(
                    f"{name} ({LAYERS[here[0]][0]}) imports {dep} ({LAYERS[there[0]][0]}, higher)"
                )
            elif there[0] == here[0] and here[2] and there[1] != here[1]:
                bad.append(f"{name} imports {dep}: independent modules of {LAYERS[here[0]][0]}")
    assert not bad, "imports running back up the pipeline:\n" + "\n".join(bad)


@pytest.mark.parametrize(
    ("source", "expected"),
    [
        ("from odofuse import se2\n", {"odofuse.se2"}),
        ("def f():\n    from odofuse.io.atomic import atomic_write\n", {"odofuse.io.atomic"}),
        ("import odofuse.motion as m\n", {"odofuse.motion"}),
        (
            "import importlib\nimportlib.import_module('odofuse.teaching.cli')\n",
            {"odofuse.teaching.cli"},
        ),
        ("from odofuse.estimators import get_estimator\n", {"odofuse.estimators"}),
        ("import numpy\n", set()),
    ],
)
def test_the_import_parser_sees_every_kind_of_import(tmp_path, source, expected):
    path = tmp_path / "probe.py"
    path.write_text(source, encoding="utf-8")
    assert imports_of("odofuse.probe", path) == expected
