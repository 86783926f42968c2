"""Programs the reader accepts but a planner may refuse: the daemon's planning step
(service.planner.plan_job) either plans them or rejects them with lines that name the
program, like every other input error."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nurbsmotion.config import load_config
from nurbsmotion.errors import InputError
from nurbsmotion.service.planner import plan_job

ROOT = Path(__file__).resolve().parents[2]
WANG = (ROOT / "examples" / "wang_table1.nc").read_text()
# found by mutating examples (tests/program/test_fuzz.mutate): a NURBS control point losing its Y Z R
HARD = {"wang_short_point.nc": WANG.replace("N160 K0.72 X-80 Y-30 Z-30 R25", "N160 K0.72 X-8")}


@pytest.mark.parametrize("name", list(HARD))
def test_a_program_a_planner_refuses_is_rejected_naming_the_program(name):
    config = load_config(ROOT / "config" / "demo.yaml")
    try:
        plan_job(name, HARD[name], config, np.zeros(3))
    except InputError as err:
        assert all(line.startswith(name) for line in str(err).splitlines()), str(err)
