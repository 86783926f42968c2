"""The ``tools:`` and ``spindle:`` keys of the machine configuration.

```yaml
tools: tools.yaml   # the tool table (docs/programs.md), relative to this file
spindle: none       # there is no spindle drive: programs with M3/M4 are refused
```

(``spindle:`` may instead describe the spindle drive, see config.spindle.)

``tools`` is read with the program package's tool-table reader when the configuration is
loaded: a missing file is an error at the ``tools`` line, a bad table one error per problem
at the table's own line (``tools.yaml:4: tools[0].length_mm: ...``). ``spindle: none`` and
an absent key both mean no spindle; a mapping is read by config.spindle.
config.py calls :func:`read_tools`, :func:`read_spindle` and :func:`load_tool_file`.
The tool-table reader is imported only when a configuration names a table: importing the
program package (numpy, the G-code reader) would add ~0.14 s to every command that reads a
configuration.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from nurbsmotion.config.yaml_reading import MISSING, SHOWN, Doc, string
from nurbsmotion.errors import InputError
from nurbsmotion.config.spindle import read_spindle_drive

if TYPE_CHECKING:
    from nurbsmotion.program.tools import ToolTable

SPINDLE_CHOICES = ("none",)


def read_tools(doc: Doc) -> Any:
    """``tools: FILE`` -> the path as written (loaded once the config's folder is known)."""
    return string(doc)


def read_spindle(doc: Doc) -> Any:
    """``spindle: none`` (YAML reads a bare ``none`` as the string; ``null`` means absent), or
    the spindle drive's mapping (config.spindle)."""
    if isinstance(doc.node, yaml.MappingNode):
        return read_spindle_drive(doc)
    value = doc.value()
    if value not in SPINDLE_CHOICES:
        doc.fail(f"must be 'none' or a spindle drive mapping (node_id, counts_per_rev, max_rpm, accel_rpm_s, ...), "
                 f"got {SHOWN.repr(value)}")
        return MISSING
    return value


def load_tool_file(tools: str, where: str, base_dir: Path | None) -> tuple[str, ToolTable]:
    """Resolve ``tools`` against the configuration's folder and read the table: (its path,
    the table). Errors: ``where`` (the config's ``tools`` line) for a missing file, the
    table's lines for its problems."""
    from nurbsmotion.program.tools import load_tool_table  # the one tool-table reader (module docstring)

    path = Path(tools)
    if base_dir is not None and not path.is_absolute():
        path = (base_dir / path).resolve()
    if not path.is_file():
        raise InputError(where, f"tool table {str(path)!r} does not exist")
    return str(path), load_tool_table(path)  # errors at the table's lines
