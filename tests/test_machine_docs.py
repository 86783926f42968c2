"""The configuration examples of docs/machine.md are valid configurations."""

import re
from pathlib import Path

from nurbsmotion.config import parse_config
from nurbsmotion.config.homing import HERE

DOC = Path(__file__).resolve().parents[1] / "docs" / "machine.md"


def _yaml_blocks() -> list[str]:
    return re.findall(r"```yaml\n(.*?)```", DOC.read_text(encoding="utf-8"), flags=re.S)


def test_homing_example_parses():
    block = next(b for b in _yaml_blocks() if "homing:" in b)
    axes = parse_config(block, "machine.md").axes
    assert axes[0].homing.method == 17 and axes[0].homing.offset_mm == -2.0
    assert axes[1].homing.method == HERE


def test_io_example_parses():
    block = next(b for b in _yaml_blocks() if b.startswith("io:"))
    io = parse_config("axes: [{name: X, node_id: 1}]\n" + block, "machine.md").io
    assert io.node_id == 10 and io.inputs[0].active_low and [s.name for s in io.outputs] == ["coolant_flood",
                                                                                           "coolant_mist"]
