"""The servo model: lag, velocity limit, quick-stop ramp (no bus)."""

from __future__ import annotations

import pytest

from nurbsmotion.sim import ServoModel


def run(servo: ServoModel, demands: list[float], period_s: float = 1e-3) -> list[float]:
    return [servo.step(d, period_s) for d in demands]


@pytest.mark.parametrize("lag", [0, 1, 3])
def test_actual_is_the_demand_delayed_by_lag_cycles(lag: int) -> None:
    demands = [float(10 * k) for k in range(1, 11)]
    actual = run(ServoModel(lag_cycles=lag), demands)
    assert actual == [0.0] * lag + demands[: len(demands) - lag]


def test_velocity_limit_caps_the_step_per_cycle() -> None:
    servo = ServoModel(lag_cycles=0, max_velocity_counts_s=2000.0)
    assert run(servo, [100.0] * 3, period_s=0.01) == [20.0, 40.0, 60.0]
    assert servo.velocity_counts_s == pytest.approx(2000.0)


def test_stalled_motor_does_not_move() -> None:
    servo = ServoModel(lag_cycles=0)
    servo.stalled = True
    assert run(servo, [5.0, 6.0]) == [0.0, 0.0]


def test_quick_stop_ramp_reaches_standstill_with_the_deceleration() -> None:
    servo = ServoModel(lag_cycles=0)
    run(servo, [10.0, 20.0])  # 10 counts per 1 ms cycle = 10000 counts/s
    positions = []
    while not servo.ramp_down(2_000_000.0, 1e-3):  # 2 counts/ms less each cycle
        positions.append(servo.actual)
    assert positions == [28.0, 34.0, 38.0, 40.0]
    assert servo.velocity_counts_s == 0.0


def test_hold_refills_the_lag_line() -> None:
    servo = ServoModel(lag_cycles=2)
    servo.hold(500.0)
    assert run(servo, [500.0, 600.0, 600.0]) == [500.0, 500.0, 500.0]


def test_bad_parameters_are_refused() -> None:
    with pytest.raises(ValueError):
        ServoModel(lag_cycles=-1)
    with pytest.raises(ValueError):
        ServoModel(max_velocity_counts_s=0)
