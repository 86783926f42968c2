"""Bus-load check: worst-case frame bits per DLC and refusal of overloaded configurations."""

import pytest

from nurbsmotion.config import parse_config
from nurbsmotion.errors import InputError
from nurbsmotion.fieldbus.busload import check_bus_load, cyclic_bus_load, fits_following_error_tpdo, frame_bits


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
