"""The master's homing procedure (fieldbus.homing) against the simulated drive's homing
(sim.homing), without a bus: two independent implementations of CiA 402-2 homing mode meet
through the controlword and statusword only, with the CiA-301 one-cycle delay of each."""

import pytest

from nurbsmotion.fieldbus.homing import HomingProcedure, homing_drive_values
from nurbsmotion.config.homing import HomingConfig
from nurbsmotion.sim.homing import HomeSensors, HomingSetup, homing_tick, idle

T = 0.004
OE = 0x0237
SENSORS = HomeSensors(negative_limit_counts=-10_000, positive_limit_counts=50_000, index_pitch_counts=4000,
                      index_phase_counts=1000)


def _home(method, offset_mm, timeout_s=20.0, sensors=SENSORS):
    config = HomingConfig(method=method, speed_search_mm_s=20, speed_zero_mm_s=2, accel_mm_s2=200,
                          offset_mm=offset_mm, timeout_s=timeout_s)
    values = homing_drive_values(config, counts_per_mm=1000, invert=False, offset_counts=0, axis_name="X")
    setup = HomingSetup(values.method, values.speed_search, values.speed_zero, values.acceleration, values.home_offset)
    master = HomingProcedure(4, method, cycle_period_s=T, timeout_s=timeout_s)
    drive = idle(20_000.0)
    statusword, controlword = OE | drive.statusword_bits, 0x0F
    for _ in range(100_000):
        step = master.step(statusword)  # sees the TPDO of the last SYNC
        drive = homing_tick(drive, setup, sensors, bool(controlword & 0x10), T)  # applies last cycle's RPDO
        statusword, controlword = OE | drive.statusword_bits, step.controlword
        if step.outcome is not None:
            return step.outcome, drive
    raise AssertionError("no outcome")


@pytest.mark.parametrize("method", [1, 2, 17, 18, 33, 34, 37])
def test_every_method_homes_and_the_home_reads_offset_mm(method):
    outcome, drive = _home(method, offset_mm=-3.5)
    assert outcome.homed, outcome.reason
    home_raw = {1: -7000, 2: 49_000, 17: -10_000, 18: 50_000, 33: 17_000, 34: 21_000, 37: 20_000}[method]
    # the drive reports -0x607C at the home; the master wrote 0x607C so that this is offset_mm.
    # Index pulses are latched exactly; a switch is sampled once per cycle: within speed_zero·T.
    resolution = 2000 * T if method in (17, 18) else 1e-6
    assert abs(home_raw + drive.shift - (-3500)) <= resolution


def test_a_drive_homing_error_reaches_the_master_as_one_line():
    outcome, _ = _home(34, 0.0, sensors=HomeSensors(positive_limit_counts=50_000))
    assert not outcome.homed
    assert outcome.reason.startswith("node 4: homing method 34: the drive reports a homing error (statusword 0x2")


def test_timeout_interrupts_the_drive():
    outcome, drive = _home(1, 0.0, timeout_s=0.5)
    assert outcome.reason.startswith("node 4: homing method 1: not completed within 0.5 s")
    drive = homing_tick(drive, HomingSetup(1, 20000, 2000, 200000, 0), SENSORS, False, T)
    assert drive.phase.value == "stopping, interrupted"
