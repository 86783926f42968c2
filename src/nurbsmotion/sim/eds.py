"""Where the drive description (EDS) of the simulated servo lives."""

from __future__ import annotations

from pathlib import Path

EDS_NAME = "nurbsmotion-servo.eds"


def default_eds_path() -> Path:
    """Path of eds/nurbsmotion-servo.eds: the repository's eds/ dir (src layout), else a copy
    installed next to this module."""
    here = Path(__file__).resolve().parent
    candidates = (here.parents[2] / "eds" / EDS_NAME, here / EDS_NAME)
    for path in candidates:
        if path.is_file():
            return path
    raise FileNotFoundError(f"{EDS_NAME} not found in {', '.join(str(p.parent) for p in candidates)}")
