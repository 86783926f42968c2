"""Bus-load check: worst-case frame bits per DLC and refusal of overloaded configurations."""

import pytest

from nurbsmotion.config import parse_config
from nurbsmotion.errors import InputError
from nurbsmotion.fieldbus.busload import (check_bus_load, config_bus_load, cyclic_bus_load, fits_following_error_tpdo,
                                         frame_bits)


def test_frame_bits_worst_case_with_stuffing():
    assert frame_bits(8) == 135  # the figure CAN references quote for 8 data bytes
    assert frame_bits(0) == 55
    with pytest.raises(ValueError):
        frame_bits(9)


def test_load_is_bits_per_cycle_over_bitrate_times_period():
    load = cyclic_bus_load(3, 0.001, 1_000_000)
    assert load.bits_per_cycle == frame_bits(0) + 3 * 2 * frame_bits(6)
    assert load.load == pytest.approx(load.bits_per_cycle / 1000.0)


def _config(n_axes: int, period_ms: float, max_load: float = 0.8):
    axes = "".join(f"  - {{name: A{i}, node_id: {i + 1}}}\n" for i in range(n_axes))
    return parse_config(f"cycle_period_ms: {period_ms}\nmonitoring: {{max_bus_load: {max_load}}}\naxes:\n{axes}",
                        "m.yaml")


def test_overloaded_configuration_is_refused_with_the_load_in_the_message():
    with pytest.raises(InputError) as info:
        check_bus_load(_config(6, 1))
    text = str(info.value)
    assert text.startswith("m.yaml") and "at 1 ms with 6 axes exceeds 80%" in text
    expected = cyclic_bus_load(6, 0.001, 1_000_000, heartbeat_period_s=0.1).load
    assert f"bus load {expected:.0%}" in text


def test_light_configuration_passes_and_may_add_the_following_error_tpdo():
    assert check_bus_load(_config(3, 4)).load < 0.3
    assert fits_following_error_tpdo(_config(3, 4))
    assert not fits_following_error_tpdo(_config(3, 1))  # 3 axes at 1 ms: only TPDO1 fits


SPINDLE_CSV = "spindle: {node_id: 5, mode: csv, counts_per_rev: 4096, max_rpm: 12000, accel_rpm_s: 20000}\n"
SPINDLE_PV = "spindle: {node_id: 5, counts_per_rev: 4096, max_rpm: 12000, accel_rpm_s: 20000}\n"
IO = "io: {node_id: 10, inputs: {estop: {bit: 0}}}\n"


def _machine(extra: str, period_ms: float = 1, max_load: float = 0.8):
    axes = "".join(f"  - {{name: A{i}, node_id: {i + 1}}}\n" for i in range(3))
    return parse_config(f"cycle_period_ms: {period_ms}\nmonitoring: {{max_bus_load: {max_load}}}\n{extra}axes:\n{axes}",
                        "m.yaml")


def test_a_csv_spindle_adds_its_0x60ff_frame_every_cycle_and_its_monitor():
    plain = config_bus_load(_machine("")).bits_per_cycle
    csv = config_bus_load(_machine(SPINDLE_CSV)).bits_per_cycle
    pv = config_bus_load(_machine(SPINDLE_PV)).bits_per_cycle
    heartbeat = frame_bits(1) * 0.001 / 0.1  # one more producer at 100 ms, per 1 ms cycle
    monitor = 4 / 0.05 * frame_bits(8) * 0.001  # 0x6041 and 0x606C read every 50 ms by SDO
    assert pv == pytest.approx(plain + heartbeat + monitor)
    assert csv == pytest.approx(pv + frame_bits(4))


def test_an_io_node_adds_its_heartbeat():
    assert config_bus_load(_machine(IO)).bits_per_cycle == pytest.approx(
        config_bus_load(_machine("")).bits_per_cycle + frame_bits(1) * 0.001 / 0.1)


def test_a_csv_spindle_can_tip_the_bus_over_the_limit_and_the_refusal_names_it():
    check_bus_load(_machine(""))  # three axes at 1 ms and 1 Mbit/s: 75 %
    with pytest.raises(InputError) as info:  # + 0x60FF every ms (9.5 %), the monitor, two heartbeats
        check_bus_load(_machine(SPINDLE_CSV + IO))
    assert "bus load 85% at 1 ms with 3 axes and 2 other nodes (spindle, I/O) exceeds 80%" in str(info.value)
