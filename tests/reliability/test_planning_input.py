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


# Programs the mutation fuzzer produced that once crashed the planners (a repeated control
# point: zero speed); now the readers reject them naming the line.
STOPS_DEAD = {
    "wang_doubled_point.nc": WANG.replace("N90 K0.2 X100 Y0 Z0 R25\n", "N90 K0.2 X100 Y0 Z0 R25\nN95 K0.2 X100 Y0 Z0 R25\n"),
    "g52_doubled_point.nc": "G21 G90 G17 G1 X1 Y2 F100\nG5.2 X1 Y1 P2 L3\nX3 Y0\nX4 Y2 P0.5\nX4 Y2 P0.5\nG5.3\nG1 X0 Y0\n",
}


@pytest.mark.parametrize("name", list(STOPS_DEAD))
def test_a_curve_that_stops_dead_is_rejected_before_planning(name):
    config = load_config(ROOT / "config" / "demo.yaml")
    with pytest.raises(InputError) as info:
        plan_job(name, STOPS_DEAD[name], config, np.zeros(3))
    assert str(info.value).startswith(f"{name}:") and "repeats control point" in str(info.value)


@pytest.mark.parametrize("algorithm", ["lookahead", "wang"])
def test_mutated_programs_are_planned_or_rejected_never_crash(algorithm):
    """Mutations of the examples through the daemon's planning step: a plan or InputError."""
    import dataclasses
    import random

    from tests.program.test_fuzz import mutate

    config = load_config(ROOT / "config" / "demo.yaml")
    config = dataclasses.replace(config, interpolation=dataclasses.replace(config.interpolation, algorithm=algorithm))
    bases = [WANG, (ROOT / "examples" / "mixed.nc").read_text()]
    rng = random.Random(20261122)
    for i in range(40):
        text = mutate(bases[i % 2], rng)
        try:
            plan_job("fz.nc", text, config, np.zeros(3))
        except InputError as err:
            assert all(line.startswith("fz.nc") for line in str(err).splitlines()), str(err)
