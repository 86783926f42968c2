"""Files the installed package carries for ``nurbsmotion demo``: copies of config/demo.yaml
and examples/wang_table1.nc (a test keeps them identical), so a non-editable install runs
the demo without the repository."""

from __future__ import annotations

from importlib import resources


def read_text(name: str) -> str:
    return resources.files(__name__).joinpath(name).read_text(encoding="utf-8")
