"""The ``tools:`` and ``spindle:`` keys of the machine configuration.

```yaml
tools: tools.yaml   # the tool table (docs/programs.md), relative to this file
spindle: none       # there is no spindle drive: programs with M3/M4 are refused
```

(``spindle:`` may instead describe the spindle drive, see spindle_config.)

``tools`` is read with the program package's tool-table reader when the configuration is
loaded: a missing file is an error at the ``tools`` line, a bad table one error per problem
at the table's own line (``tools.yaml:4: tools[0].length_mm: ...``). ``spindle: none`` and
an absent key both mean no spindle; a mapping is read by spindle_config.
config.py calls :func:`read_tools`, :func:`read_spindle` and :func:`load_tool_file`.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from nurbsmotion.config import _MISSING, _SHOWN, _Doc, _string
from nurbsmotion.errors import InputError

if TYPE_CHECKING:
    from nurbsmotion.config import MachineConfig

SPINDLE_CHOICES = ("none",)


def read_tools(doc: _Doc) -> Any:
    """``tools: FILE`` -> the path as written (loaded once the config's folder is known)."""
    return _string(doc)


def read_spindle(doc: _Doc) -> Any:
    """``spindle: none`` (YAML reads a bare ``none`` as the string; ``null`` means absent), or
    the spindle drive's mapping (spindle_config)."""
    if isinstance(doc.node, yaml.MappingNode):
        from nurbsmotion.spindle_config import read_spindle_drive
        return read_spindle_drive(doc)
    value = doc.value()
    if value not in SPINDLE_CHOICES:
        doc.fail(f"must be 'none' or a spindle drive mapping (node_id, counts_per_rev, max_rpm, accel_rpm_s, ...), "
                 f"got {_SHOWN.repr(value)}")
        return _MISSING
    return value


def load_tool_file(cfg: "MachineConfig", base_dir: Path | None) -> "MachineConfig":
    """Resolve ``tools`` against the configuration's folder and read the table (errors:
    the config line for an unreadable file, the table's lines for its problems)."""
    if cfg.tools is None:
        return cfg
    from nurbsmotion.program.tools import load_tool_table  # the one tool-table reader

    path = Path(cfg.tools)
    if base_dir is not None and not path.is_absolute():
        path = (base_dir / path).resolve()
    if not path.is_file():
        raise InputError(cfg.where("tools"), f"tool table {str(path)!r} does not exist")
    return replace(cfg, tools=str(path), tool_table=load_tool_table(path))  # errors at the table's lines
