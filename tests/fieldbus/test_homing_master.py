"""The master homes one axis of simulated drives on a private virtual bus (CiA-402 mode 6)
while the others hold: the home reads offset_mm, nothing else moves, the streaming mode and
the hold come back without a jump; a homing error is one line and leaves the axes holding."""

from __future__ import annotations

import contextlib
import time
import uuid

import can
import numpy as np
import pytest

from nurbsmotion.fieldbus import Master
from nurbsmotion.fieldbus.homing import HomingProcedure, homing_drive_values, homing_plan
from nurbsmotion.config.homing import HomingConfig

sim_package = pytest.importorskip("nurbsmotion.sim")
SimNetwork = sim_package.SimNetwork
HomeSensors = pytest.importorskip("nurbsmotion.sim.homing").HomeSensors

from tests.fieldbus.test_master_sim import make_config  # noqa: E402

SENSORS = HomeSensors(negative_limit_counts=-3000, positive_limit_counts=5000, index_pitch_counts=2000,
                      index_phase_counts=500)


@contextlib.contextmanager
def homing_rig(mode: str):
    channel = "home-" + uuid.uuid4().hex
    sim = SimNetwork(channel=channel)
    for node in (1, 2):
        sim.add_drive(node, identity=(0x1234, 0x42), home_sensors=SENSORS)
    sim.start()
    bus = can.Bus(interface="virtual", channel=channel)
    master = Master(make_config(channel, mode, 2), bus, bootup_timeout_s=1.0)
    try:
        master.bring_up()
        yield master, sim
    finally:
        master.shutdown()
        bus.shutdown()
        sim.stop()


def _home(master: Master, method: int, offset_mm: float, timeout_s: float = 20.0):
    config = HomingConfig(method=method, speed_search_mm_s=20, speed_zero_mm_s=2, accel_mm_s2=200,
                          offset_mm=offset_mm, timeout_s=timeout_s)
    values = homing_drive_values(config, 1000, False, 0, "X")
    plan = homing_plan(values, master.plans[0].mode)
    return master.home(0, plan, HomingProcedure(1, method, master.config.cycle_period_s, timeout_s))


@pytest.mark.parametrize("mode", ["csp", "ip"])
def test_homing_method_17_reads_offset_mm_and_the_other_axis_holds(mode):
    with homing_rig(mode) as (master, sim):
        y_before = master.status().axes[1].position_counts
        outcome = _home(master, 17, offset_mm=-2.5)
        assert outcome.homed, outcome.reason
        status = master.status()
        assert status.phase == "holding"
        x = status.axes[0]
        # the home (the negative switch's edge, sampled once per cycle at speed_zero) reads -2.5 mm;
        # the drive comes to rest beyond it by speed_zero²/(2·accel) = 2²/400 mm = 10 counts
        assert abs(x.position_counts - (-2500 + 10)) <= 2000 * master.config.cycle_period_s + 1
        assert abs(x.setpoint_counts - x.position_counts) <= 1  # hold where it stands: no jump
        assert status.axes[1].position_counts == y_before
        assert not master.faults()
        # streaming works again from there
        start = np.array([[x.setpoint_counts, status.axes[1].setpoint_counts]], dtype=np.int32)
        rows = start + np.column_stack([np.linspace(0, 1000, 200), np.zeros(200)]).astype(np.int32)
        assert master.stream(rows).wait(30).outcome == "done"


def test_homing_error_is_one_line_and_the_axes_keep_holding():
    with homing_rig("csp") as (master, sim):
        sim[1].axis.home_sensors = HomeSensors(positive_limit_counts=5000)  # no index pulse: method 34 fails
        outcome = _home(master, 34, 0.0)
        assert not outcome.homed
        assert outcome.reason.startswith("axis X: node 1: homing method 34: the drive reports a homing error") \
            or outcome.reason.startswith("node 1: homing method 34: the drive reports a homing error"), outcome.reason
        assert master.status().phase == "holding"
        assert not master.faults()


def test_timeout_interrupts_and_restores():
    with homing_rig("csp") as (master, sim):
        t0 = time.monotonic()
        outcome = _home(master, 1, 0.0, timeout_s=0.3)
        assert not outcome.homed and "not completed within 0.3 s" in outcome.reason
        assert time.monotonic() - t0 < 10
        assert master.status().phase == "holding"
        assert not master.faults()


def test_a_method_the_drive_refuses_is_one_line_and_the_axes_keep_holding():
    from nurbsmotion.errors import FieldbusError

    with homing_rig("csp") as (master, sim):
        with pytest.raises(FieldbusError) as err:
            _home(master, 19, 0.0)  # the simulated drive implements 1, 2, 17, 18, 33, 34, 35, 37
        assert str(err.value).startswith("axis X: node 1: homing method 19: step 'homing configuration': SDO abort "
                                         "0x06090030")
        assert "\n" not in str(err.value)
        assert master.status().phase == "holding" and not master.faults()
        assert sim[1].axis.mode_display == 8  # never left CSP
