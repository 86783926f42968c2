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
