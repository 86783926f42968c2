"""Files the installed package carries for ``nurbsmotion demo``: config/demo.yaml,
examples/wang_table1.nc and eds/nurbsmotion-servo.eds. In the repository they are symlinks
to those files (so they cannot drift); building the package copies their content, so a
non-editable install runs the demo without the repository."""

from __future__ import annotations

from importlib import resources
from pathlib import Path


def read_text(name: str) -> str:
    return resources.files(__name__).joinpath(name).read_text(encoding="utf-8")


def path(name: str) -> Path:
    """File system path of a packaged file (the package is installed as plain files)."""
    return Path(str(resources.files(__name__).joinpath(name)))
