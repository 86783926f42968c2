"""The path's verified extremes (service.path_bounds) against dense sampling, and the soft-limit
refusal of a streamed job before any planning (service.streamed_job.check_before_motion)."""

from pathlib import Path

import numpy as np
import pytest

from nurbsmotion.config import load_config
from nurbsmotion.errors import InputError
from nurbsmotion.geometry.primitives import arc_curve
from nurbsmotion.program import parse_gcode, read_program
from nurbsmotion.program.summary import curve_samples
from nurbsmotion.service import path_bounds
from nurbsmotion.service.path_bounds import BRACKET_MM, curve_extreme
from nurbsmotion.service.streamed_job import prepare_streamed_job

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def config():
    return load_config(ROOT / "config" / "demo.yaml")  # soft limits [-200, 200] on X, Y, Z


def dense_extreme(curve, j, sign, n=200001):
    u = np.linspace(curve.u_min, curve.u_max, n)
    return float((sign * curve.points(u)[:, j]).max())


@pytest.mark.parametrize("sweep", [np.pi / 3, np.pi, 1.5 * np.pi])
def test_an_arc_bulge_is_bracketed_to_its_exact_extreme(sweep):
    curve = arc_curve((170.0, 0.0, 0.0), (170.0, -50.0, 0.0), sweep)
    for j, sign in ((0, 1.0), (0, -1.0), (1, 1.0)):
        extreme = curve_extreme(curve, j, sign)
        dense = dense_extreme(curve, j, sign)
        assert extreme.reached <= extreme.bound <= extreme.reached + BRACKET_MM
        assert extreme.bound >= dense - 1e-9 and extreme.reached >= dense - 1e-6


def test_wang_curve_extremes_bound_every_point():
    program = read_program(ROOT / "src" / "nurbsmotion" / "data" / "wang_table1.nc")
    for block in program.blocks:
        for j in range(2):
            for sign in (1.0, -1.0):
                extreme = curve_extreme(block.curve, j, sign)
                dense = dense_extreme(block.curve, j, sign, 20001)
                assert extreme.bound >= dense - 1e-9 and extreme.bound - extreme.reached <= BRACKET_MM


def test_a_streamed_job_is_refused_at_the_line_of_an_arc_bulging_past_a_soft_limit(config, planner_worker):
    program = "G21 G90 G17\nG01 X170 Y-50 F3000\nG03 X170 Y50 I0 J50\n"
    with pytest.raises(InputError) as info:
        prepare_streamed_job("arc.nc", program, config, planner_worker, np.zeros(3))
    message = str(info.value)
    assert message.startswith("arc.nc:3: axis X would reach ") and message.endswith(", beyond the soft limit 200 mm")
    assert float(message.split("reach ")[1].split(" mm")[0]) == pytest.approx(220.0, abs=1e-6)


def test_a_line_beyond_the_limit_names_its_word_before_planning(config, planner_worker):
    program = "G21 G90\nG01 X10 F3000\nG01 Y-20\n(comment)\nG01 X250 Y-20\nG01 X0\n"
    with pytest.raises(InputError) as info:
        prepare_streamed_job("part.nc", program, config, planner_worker, np.zeros(3))
    assert str(info.value) == "part.nc:5: X250: axis X would reach 250 mm, beyond the soft limit 200 mm"


def test_an_arc_just_inside_the_limit_is_accepted(config, planner_worker):
    program = "G21 G90 G17\nG01 X149.9999 Y-50 F3000\nG03 X149.9999 Y50 I0 J50\n"  # bulge to 199.9999
    job = prepare_streamed_job("arc.nc", program, config, planner_worker, np.zeros(3))
    job.cancel()


def _per_block_reference(program, config, columns):
    """The checks as one loop per block (how path_bounds computed them before block_boxes):
    (first unconfigured column moved, first soft-limit error text, the control points' box)."""
    moved = next((j for b in program.blocks for j in range(3)
                  if j not in columns and np.ptp(b.curve.control_points[:, j]) > 1e-9), None)
    error = None
    for block in program.blocks:
        for axis, col in zip(config.axes, columns):
            low, high = axis.soft_limits_mm
            for sign, limit in ((1.0, high), (-1.0, low)):
                if error is None and (sign * block.curve.control_points[:, col]).max() > sign * limit:
                    extreme = curve_extreme(block.curve, col, sign)
                    if max(extreme.reached, extreme.bound) > sign * limit + BRACKET_MM:
                        error = str(path_bounds._violation(block.source, axis.name, sign * extreme.reached, limit))
    lows = np.min([b.curve.control_points[:, columns].min(axis=0) for b in program.blocks], axis=0)
    highs = np.max([b.curve.control_points[:, columns].max(axis=0) for b in program.blocks], axis=0)
    return moved, error, lows, highs


@pytest.mark.parametrize("seed", range(8))
def test_whole_program_checks_agree_with_a_loop_over_the_blocks(config, seed):
    """block_boxes gives all blocks' boxes at once: same first axis, same first error line; the
    path's box holds every sampled point of the path and lies within the control points' box."""
    rng = np.random.default_rng(seed)
    lines = ["G21 G90 G17 F3000"]
    for _ in range(60):
        x, y, z = rng.uniform(-230, 230, 3) if rng.random() < 0.05 else rng.uniform(-150, 150, 3)
        lines.append(f"G01 X{x:.3f} Y{y:.3f} Z{z:.3f}" if rng.random() < 0.6 else f"G02 X{x:.3f} Y{y:.3f} R{rng.uniform(150, 300):.3f}")
    try:
        program = parse_gcode("\n".join(lines), "r.nc")
    except InputError:
        pytest.skip("an R too small for its chord")
    for columns in ([0, 1, 2], [0, 1]):
        moved, error, lows, highs = _per_block_reference(program, config, columns)
        assert path_bounds.moving_unconfigured_axis(program, columns) == moved
        found = path_bounds.soft_limit_violation(program, config, columns)
        assert (str(found) if found else None) == error
        low, high = path_bounds.path_box(program, columns)
        assert np.all(low >= lows - 1e-9) and np.all(high <= highs + 1e-9)
        samples = np.vstack([curve_samples(b.curve, 1024)[:, columns] for b in program.blocks])
        assert np.all(samples >= low - 1e-9) and np.all(samples <= high + 1e-9)
        np.testing.assert_allclose(low, samples.min(axis=0), atol=1e-4)  # r (1 - cos(pi / 4096)), r <= 300
        np.testing.assert_allclose(high, samples.max(axis=0), atol=1e-4)
