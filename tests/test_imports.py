"""The import graph of src/lossvo, counting imports inside functions and under ``if TYPE_CHECKING:``: no
cycles, and no module importing a layer above its own."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"


def module_name(path: Path) -> str:
    parts = list(path.relative_to(SRC).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported(source: str, name: str, is_package: bool, modules: set[str]) -> set[str]:
    """The lossvo modules that module ``name`` imports anywhere in its ``source`` (``from a import b``
    counts ``a.b`` when that is a module, else ``a``; a package's ``__init__`` runs with any of its
    modules)."""
    package = name if is_package else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(
                    [*package.split(".")[: len(package.split(".")) - node.level + 1], base]
                ).strip(".")
            found.update(f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names)
    edges = set()
    for target in found:
        while target and target not in modules:
            target = target.rpartition(".")[0]
        parts = target.split(".")
        edges.update(".".join(parts[:i]) for i in range(2, len(parts) + 1))  # parents' __init__ run first
    edges.discard(name)
    return {e for e in edges if e in modules and not name.startswith(e + ".")}


def graph() -> dict[str, set[str]]:
    files = {module_name(p): p for p in (SRC / "lossvo").rglob("*.py")}
    return {
        name: imported(path.read_text(), name, path.name == "__init__.py", set(files))
        for name, path in files.items()
    }


def find_cycle(edges: dict[str, set[str]]) -> list[str] | None:
    """One cycle of the directed graph as a list of nodes (first = last), or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(edges.get(node, ())):
            if state.get(nxt) == 1:
                return [*stack[stack.index(nxt) :], nxt]
            if nxt not in state and (cycle := visit(nxt)):
                return cycle
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(edges):
        if node not in state and (cycle := visit(node)):
            return cycle
    return None


def test_no_import_cycles() -> None:
    edges = graph()
    assert len(edges) > 30 and "lossvo.training.fitting" in edges["lossvo.train"]
    cycle = find_cycle(edges)
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


@pytest.mark.parametrize(
    ("edges", "cyclic"),
    [({"a": {"b"}, "b": {"c"}, "c": {"a"}}, True), ({"a": {"b"}, "b": {"c"}, "c": set()}, False)],
)
def test_cycle_finder(edges: dict[str, set[str]], cyclic: bool) -> None:
    assert (find_cycle(edges) is not None) == cyclic


def test_imports_inside_functions_and_type_checking_count() -> None:
    source = (
        "from typing import TYPE_CHECKING\n"
        "if TYPE_CHECKING:\n    from lossvo.b import X\n"
        "def f():\n    from lossvo import c\n    from .d import y\n"
    )
    modules = {"lossvo", "lossvo.a", "lossvo.b", "lossvo.c", "lossvo.d", "lossvo.e"}
    assert imported(source, "lossvo.a", False, modules) == {"lossvo.b", "lossvo.c", "lossvo.d"}


ENTRIES = {
    "lossvo.train", "lossvo.study", "lossvo.eval", "lossvo.metrics", "lossvo.report.cli",
    "lossvo.report.__main__", "lossvo.data.synthetic.cli", "lossvo.data.synthetic.__main__",
    "lossvo.motion", "lossvo.axioms",
}  # fmt: skip
"""Modules that parse a command line: the entry points, including the dataset generator's inside data/."""

LAYERS = (
    ("report",),
    ("training",),
    ("evaluation",),
    ("data", "losses", "weighting", "models"),
    ("geometry",),
    (
        "console",
        "atomic",
        "processes",
        "checks",
        "folder_lock",
        "output_folders",
        "code_version",
        "machine",
        "table_render",
    ),
)
"""The library's layers, top to bottom, by the first name under ``lossvo``; each imports only its own
layer and the ones below it."""


def layer(module: str) -> int:
    """0 for an entry point, then 1, 2, ... down the :data:`LAYERS`; the package ``lossvo`` is the lowest."""
    if module in ENTRIES:
        return 0
    parts = module.split(".")
    if len(parts) == 1:
        return len(LAYERS) + 1
    return 1 + next(i for i, names in enumerate(LAYERS) if parts[1] in names)


def upward_imports(edges: dict[str, set[str]]) -> list[str]:
    """``"a -> b"`` for each import of a module ``b`` in a layer above ``a``'s (an entry counts as the
    top layer, so a library module importing any entry point is listed)."""
    return sorted(f"{a} -> {b}" for a, targets in edges.items() for b in targets if layer(b) < layer(a))


def test_every_module_has_a_layer() -> None:
    for module in graph():
        layer(module)  # StopIteration for a package the layers do not name


def test_no_module_imports_a_layer_above_its_own() -> None:
    edges = graph()
    assert set(edges) >= ENTRIES - {"lossvo.report.__main__"}  # the entries listed exist
    assert upward_imports(edges) == []


def test_upward_imports_are_found() -> None:
    edges = {
        "lossvo.evaluation.results": {"lossvo.training.module"},
        "lossvo.training.fitting": {"lossvo.evaluation.results", "lossvo.train"},
        "lossvo.train": {"lossvo.training.fitting"},
    }
    assert upward_imports(edges) == [
        "lossvo.evaluation.results -> lossvo.training.module", "lossvo.training.fitting -> lossvo.train"
    ]  # fmt: skip


def test_camera_maths_sits_below_data_and_models() -> None:
    """The camera's maths (K after resizing or mirroring, the intrinsics layer) is imported by both the data
    readers and the networks, so it lives in geometry/, below both."""
    edges = graph()
    assert "lossvo.geometry.camera" in edges["lossvo.models.flowvo"]
    assert "lossvo.geometry.camera" in edges["lossvo.data.tum"]
    assert layer("lossvo.geometry.camera") > max(layer("lossvo.data.tum"), layer("lossvo.models.flowvo"))
    assert not any(m.startswith("lossvo.data") for m in edges["lossvo.models.flowvo"])


PRESENTATION = ("lossvo.table_render", "lossvo.report", "lossvo.console.emit")
"""What renders or prints a command's output: the table renderer, the report, printing to stdout."""


def presentation_imports(source: str, package: str) -> set[str]:
    """The :data:`PRESENTATION` modules and names that a module of ``package`` imports anywhere in its
    ``source`` (``from a import b`` counts ``a.b``)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            parts = package.split(".")
            base = ".".join([*parts[: len(parts) - node.level + 1], node.module or ""] if node.level else
                            [node.module or ""]).strip(".")  # fmt: skip
            names.update(f"{base}.{alias.name}" for alias in node.names)
    return {n for n in names if any(n == p or n.startswith(p + ".") for p in PRESENTATION)}


@pytest.mark.parametrize(
    ("source", "found"),
    [
        ("from lossvo.table_render import Rows", {"lossvo.table_render.Rows"}),
        ("from lossvo import table_render, geometry", {"lossvo.table_render"}),
        ("def f():\n    from lossvo.console import UserError, emit", {"lossvo.console.emit"}),
        ("import lossvo.report.tables", {"lossvo.report.tables"}),
        ("from ...report import tables", {"lossvo.report.tables"}),
        ("from lossvo.console import UserError\nfrom lossvo.data import kitti", set()),
    ],
)
def test_presentation_imports_are_found(source: str, found: set[str]) -> None:
    assert presentation_imports(source, "lossvo.data.synthetic") == found


def test_geometry_and_data_render_and_print_nothing() -> None:
    """geometry/ and data/ compute; rendering tables, the report and printing a command's output live in
    the layers above (the tables of ``python -m lossvo.axioms`` and ``python -m lossvo.motion``)."""
    checked = 0
    for package in ("geometry", "data"):
        for path in sorted((SRC / "lossvo" / package).rglob("*.py")):
            name = module_name(path)
            found = presentation_imports(path.read_text(), name if path.name == "__init__.py" else
                                         name.rpartition(".")[0])  # fmt: skip
            assert not found, f"{name} imports {', '.join(sorted(found))}"
            checked += 1
    assert checked > 20


def test_the_table_renderer_sits_below_every_table() -> None:
    """The report and the command lines render tables through one module in the lowest layer."""
    edges = graph()
    for module in ("lossvo.report.tables", "lossvo.motion", "lossvo.axioms"):
        assert "lossvo.table_render" in edges[module], module
    assert layer("lossvo.table_render") > layer("lossvo.geometry.maps")
