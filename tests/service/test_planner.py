"""plan_job: soft-limit rejections name the program line and word."""

from pathlib import Path

import numpy as np
import pytest

from nurbsmotion.config import load_config
from nurbsmotion.errors import InputError
from nurbsmotion.service.planner import plan_job

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def config():
    return load_config(ROOT / "config" / "demo.yaml")  # soft limits [-200, 200] on X, Y, Z


def test_a_line_beyond_the_soft_limit_names_its_line_and_word(config):
    program = "G21 G90\nG01 X10 F3000\nG01 Y-20\n(comment)\nG01 X250 Y-20\nG01 X0\n"
    with pytest.raises(InputError) as info:
        plan_job("part.nc", program, config, np.zeros(3))
    assert str(info.value) == "part.nc:5: X250: axis X would reach 250 mm, beyond the soft limit 200 mm"


def test_the_lower_limit_and_the_first_line_in_program_order(config):
    program = "G21 G90\nG01 Z-210 F3000\nG01 X300\n"
    with pytest.raises(InputError) as info:
        plan_job("part.nc", program, config, np.zeros(3))
    assert str(info.value) == "part.nc:2: Z-210: axis Z would reach -210 mm, beyond the soft limit -200 mm"


def test_an_arc_bulging_past_the_limit_names_its_line_and_how_far(config):
    # a half circle around (170, 0), radius 50: its end points are inside, its bulge reaches X220
    program = "G21 G90 G17\nG01 X170 Y-50 F3000\nG03 X170 Y50 I0 J50\n"
    with pytest.raises(InputError) as info:
        plan_job("arc.nc", program, config, np.zeros(3))
    message = str(info.value)
    assert message.startswith("arc.nc:3: axis X would reach ") and message.endswith(", beyond the soft limit 200 mm")
    assert float(message.split("reach ")[1].split(" mm")[0]) == pytest.approx(220.0, abs=0.01)
