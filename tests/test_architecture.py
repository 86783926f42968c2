"""The dependency rules of docs/architecture (shared/reference/architecture.md), checked on
the import statements of every module: the math knows no bus, the simulator shares no code
with the master, the master knows no curves, only service and cli join the layers."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "nurbsmotion"

FORBIDDEN = {
    "geometry": ("program", "planning", "fieldbus", "sim", "service", "cli", "axes"),
    "program": ("planning", "fieldbus", "sim", "service", "cli"),
    "planning": ("fieldbus", "sim", "service", "cli"),
    "fieldbus": ("geometry", "program", "planning", "sim", "service", "cli"),
    "sim": ("fieldbus", "geometry", "program", "planning", "service", "cli", "axes"),
    "service": ("cli", "web"),
    "web": ("geometry", "program", "planning", "fieldbus", "sim", "cli", "axes"),
    # read by every layer: knows the control protocol's socket default and the tool-table reader only
    "config": ("geometry", "planning", "fieldbus", "sim", "cli", "web", "axes"),
    # shared by fieldbus and sim: CANopen constants and transport, no layer above
    "can": ("config", "geometry", "program", "planning", "fieldbus", "sim", "service", "cli", "web", "axes"),
}


def imported_layers(path: Path) -> set[str]:
    """First component below nurbsmotion of every module a file imports."""
    layers = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        names = []
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module]
        for name in names:
            parts = name.split(".")
            if parts[0] == "nurbsmotion" and len(parts) > 1:
                layers.add(parts[1])
    return layers


@pytest.mark.parametrize("layer", sorted(FORBIDDEN))
def test_layer_imports_only_what_the_architecture_allows(layer):
    offenders = []
    for path in sorted((PACKAGE / layer).rglob("*.py")):
        bad = imported_layers(path) & set(FORBIDDEN[layer])
        if bad:
            offenders.append(f"{path.relative_to(PACKAGE)} imports {', '.join(sorted(bad))}")
    assert not offenders, offenders


def test_the_web_gateway_knows_the_daemon_only_by_its_control_protocol():
    """Moonraker beside Klippy: the gateway may use service.protocol, nothing else of the daemon."""
    offenders = []
    for path in sorted((PACKAGE / "web").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("nurbsmotion.service") \
                    and node.module != "nurbsmotion.service.protocol":
                offenders.append(f"{path.relative_to(PACKAGE)} imports {node.module}")
    assert not offenders, offenders


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported_modules(path: Path, modules: set[str]) -> set[str]:
    """The package modules a file imports, anywhere in it (function-local and TYPE_CHECKING
    imports too: they hide a circle, they do not break it). ``from pkg import name`` is
    pkg.name when that is a module; the parent packages Python loads on the way are not
    counted (they are being initialised already)."""
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            targets = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else base for alias in node.names]
        else:
            continue
        found |= {target for target in targets if target in modules and target != name}
    return found


def import_circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    circles = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, targets = work[-1]
            target = next(targets, None)
            if target is not None:
                if target not in index:
                    index[target] = low[target] = len(index)
                    stack.append(target)
                    on_stack.add(target)
                    work.append((target, iter(sorted(graph[target]))))
                elif target in on_stack:
                    low[node] = min(low[node], index[target])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    circles.append(sorted(component))
    return circles


def test_the_circle_finder_finds_a_circle_through_three_modules():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert import_circles(graph) == [["a", "b", "c"]]
    assert import_circles({"a": {"b"}, "b": set()}) == []


def test_no_import_circles_in_the_package():
    """A circle makes import order matter and forces function-local imports; none is allowed."""
    paths = sorted(PACKAGE.rglob("*.py"))
    modules = {module_name(path) for path in paths}
    graph = {module_name(path): imported_modules(path, modules) for path in paths}
    assert import_circles(graph) == []



# issue 23's sizes: a class a reader can take in, modules of the bus layers a reader can take in
MAX_METHODS = 25
MAX_LINES = {"fieldbus": 600, "sim": 600}


def method_counts(source: str, module: str) -> dict[str, int]:
    """Methods defined in each class body (properties included), keyed module.Class."""
    return {f"{module}.{node.name}": sum(isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef)) for item in node.body)
            for node in ast.walk(ast.parse(source)) if isinstance(node, ast.ClassDef)}


def test_method_counts_count_the_methods_of_each_class():
    source = ("class A:\n    x = 1\n    def f(self): ...\n    @property\n    def g(self): ...\n"
              "    async def h(self): ...\n    class Inner:\n        def i(self): ...\nclass B:\n    pass\n")
    assert method_counts(source, "m") == {"m.A": 3, "m.Inner": 1, "m.B": 0}


def test_no_class_has_more_than_25_methods():
    counts = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        counts.update(method_counts(path.read_text(), module_name(path).removeprefix("nurbsmotion.")))
    too_many = {name: n for name, n in counts.items() if n > MAX_METHODS}
    assert not too_many, f"more than {MAX_METHODS} methods: {too_many}"


@pytest.mark.parametrize("layer", sorted(MAX_LINES))
def test_no_module_of_the_bus_layers_is_longer_than_600_lines(layer):
    long_modules = {str(path.relative_to(PACKAGE)): n for path in sorted((PACKAGE / layer).rglob("*.py"))
                    if (n := len(path.read_text().splitlines())) > MAX_LINES[layer]}
    assert not long_modules, long_modules
