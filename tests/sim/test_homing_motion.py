"""Simulated drive homing (CiA 402-2 homing mode): each method's motion, home and status bits."""

import itertools

import pytest

from nurbsmotion.sim.homing import (
    SW_HOMING_ATTAINED,
    SW_HOMING_ERROR,
    SW_TARGET_REACHED,
    HomeSensors,
    HomingSetup,
    Phase,
    homing_tick,
    idle,
    supported,
)

T = 0.001
SENSORS = HomeSensors(negative_limit_counts=-10_000, positive_limit_counts=50_000, index_pitch_counts=4000,
                      index_phase_counts=1000)
OFFSET = 250  # 0x607C: the home reads -250


def _setup(method, **kw):
    values = {"method": method, "speed_search_counts_s": 20_000, "speed_zero_counts_s": 2000, "accel_counts_s2": 200_000,
                  "home_offset_counts": OFFSET}
    return HomingSetup(**{**values, **kw})


def _run(method, start=20_000.0, sensors=SENSORS, max_ticks=20_000, stop_at=None, **kw):
    """Tick with bit 4 low once, then high, until the drive rests; returns states."""
    setup = _setup(method, **kw)
    state = homing_tick(idle(start), setup, sensors, False, T)
    states = [state]
    for tick in range(max_ticks):
        state = homing_tick(state, setup, sensors, stop_at is None or tick < stop_at, T)
        states.append(state)
        if state.phase in (Phase.HOMED, Phase.ERROR, Phase.INTERRUPTED):
            return states
    raise AssertionError(f"method {method} did not finish: {state}")


def _home_raw(state):
    """The raw position that reads -0x607C after homing."""
    return -OFFSET - state.shift


def _phases(states):
    out = []
    for s in states:
        if not out or out[-1] != s.phase:
            out.append(s.phase)
    return out


@pytest.mark.parametrize("method, home_raw, tolerance, switch_side", [
    (1, -7000, 0, -1),  # negative limit, back off, first index above -10000
    (2, 49_000, 0, 1),  # positive limit, back off, first index below 50000
    (17, -10_000, 2, -1),  # where the switch is seen released (sampled: within speed_zero·T)
    (18, 50_000, 2, 1),
])
def test_limit_switch_methods(method, home_raw, tolerance, switch_side):
    states = _run(method)
    last = states[-1]
    assert last.phase is Phase.HOMED
    assert abs(_home_raw(last) - home_raw) <= tolerance
    assert last.statusword_bits == SW_HOMING_ATTAINED | SW_TARGET_REACHED
    expected = [Phase.NOT_STARTED, Phase.SEARCH_SWITCH, Phase.LEAVE_SWITCH]
    expected += [Phase.SEARCH_INDEX] if method in (1, 2) else []
    assert _phases(states) == expected + [Phase.STOPPING_HOMED, Phase.HOMED]
    # it went into the switch zone, decelerating with 0x609A: 20000²/(2·200000) = 1000 counts past it
    limit = -10_000 if switch_side < 0 else 50_000
    extreme = min(s.raw for s in states) if switch_side < 0 else max(s.raw for s in states)
    assert abs(extreme - limit) == pytest.approx(1000, abs=25)
    # never faster than the search speed, speed changes within 0x609A
    speeds = [s.speed_counts_s for s in states]
    assert max(abs(v) for v in speeds) <= 20_000
    assert max(abs(b - a) for a, b in itertools.pairwise(speeds)) <= 200_000 * T + 1e-9
    # it stops after the home with 0x609A: overshoot speed_zero²/(2a) = 10 counts
    assert abs(last.raw - _home_raw(last)) == pytest.approx(10, abs=2 + tolerance)


@pytest.mark.parametrize("method, home_raw", [(33, 17_000), (34, 21_000)])
def test_index_only_methods(method, home_raw):
    states = _run(method)
    assert states[-1].phase is Phase.HOMED and _home_raw(states[-1]) == home_raw
    assert _phases(states) == [Phase.NOT_STARTED, Phase.SEARCH_INDEX, Phase.STOPPING_HOMED, Phase.HOMED]
    assert max(abs(s.speed_counts_s) for s in states) == 2000  # searched at 0x6099:02


@pytest.mark.parametrize("method", [35, 37])
def test_current_position_methods_do_not_move(method):
    states = _run(method, start=1234.0)
    assert len(states) == 2 and states[-1].raw == 1234.0
    assert states[-1].position == -OFFSET


def test_starting_on_the_switch_backs_off_at_once():
    states = _run(17, start=-10_500.0)
    assert _phases(states)[:2] == [Phase.NOT_STARTED, Phase.LEAVE_SWITCH]
    assert min(s.raw for s in states) == -10_500.0  # never moved further into the switch
    assert abs(_home_raw(states[-1]) + 10_000) <= 2


def test_index_search_without_index_pulse_ends_on_the_limit_with_an_error():
    sensors = HomeSensors(negative_limit_counts=-10_000, positive_limit_counts=50_000)
    states = _run(34, sensors=sensors)
    assert _phases(states)[-2:] == [Phase.STOPPING_ERROR, Phase.ERROR]
    assert states[-2].statusword_bits == SW_HOMING_ERROR  # error, still moving
    assert states[-1].statusword_bits == SW_HOMING_ERROR | SW_TARGET_REACHED
    assert states[-1].shift == 0.0  # no home was set


def test_wrong_limit_during_switch_search_is_an_error():
    sensors = HomeSensors(positive_limit_counts=21_000)  # method 1 searches a negative switch that is missing ...
    states = _run(1, sensors=sensors, start=22_000.0)  # ... and starts on the positive limit
    assert states[-1].phase is Phase.ERROR


def test_clearing_bit_4_interrupts_and_stops_with_the_homing_acceleration():
    states = _run(1, stop_at=50)
    assert _phases(states)[-2:] == [Phase.STOPPING_INTERRUPTED, Phase.INTERRUPTED]
    assert states[-1].statusword_bits == SW_TARGET_REACHED and states[-1].shift == 0.0
    assert states[-1].speed_counts_s == 0.0


def test_rising_edge_restarts_and_not_started_reports_target_reached():
    assert idle(0.0).statusword_bits == SW_TARGET_REACHED
    setup = _setup(37)
    state = homing_tick(idle(5.0), setup, SENSORS, True, T)  # bit 4 already high on entry counts as an edge
    assert state.phase is Phase.HOMED
    again = homing_tick(state, setup, SENSORS, True, T)
    assert again == state  # no edge, no restart


def test_supported_methods():
    assert [m for m in range(-5, 40) if supported(m)] == [1, 2, 17, 18, 33, 34, 35, 37]
    assert homing_tick(idle(0.0), _setup(3), SENSORS, True, T).phase is Phase.ERROR


def test_setup_from_the_drive_objects():
    from nurbsmotion.sim.homing import HOMING_OBJECTS, setup_from_objects

    values = {(0x6098, 0): 17, (0x6099, 1): 20_000, (0x6099, 2): 2000, (0x609A, 0): 200_000, (0x607C, 0): -5}
    assert setup_from_objects(lambda index, sub: values[(index, sub)]) == HomingSetup(17, 20_000.0, 2000.0, 200_000.0, -5)
    assert {(i, s) for i, s, _ in HOMING_OBJECTS} == set(values)


def test_a_vendor_home_object_replaces_0x607c():
    """maxon EPOS4 0x30B0 "home position" (sign +1): the home reads its value, i.e. the
    setup's home offset (the home reads minus it) is -0x30B0; 0x607C is not read."""
    from nurbsmotion.sim.homing import setup_from_objects

    values = {(0x6098, 0): 35, (0x6099, 1): 0, (0x6099, 2): 0, (0x609A, 0): 0, (0x30B0, 0): -20_000}
    setup = setup_from_objects(lambda index, sub: values[(index, sub)], (0x30B0, 1))
    assert setup.home_offset_counts == 20_000
    assert setup_from_objects(lambda index, sub: values[(index, sub)], (0x30B0, -1)).home_offset_counts == -20_000
