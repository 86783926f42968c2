"""axes[i].sim (machine mm) -> the simulated drive's HomeSensors (raw counts at power-on)."""

from nurbsmotion.config import parse_config
from nurbsmotion.sim.homing import HomeSensors
from nurbsmotion.sim.machine_sensors import machine_home_sensors


def test_mm_become_raw_counts_through_scale_and_offset():
    cfg = parse_config("axes:\n  - {name: X, node_id: 1, counts_per_mm: 1000, offset_counts: 500,\n"
                       "     sim: {negative_limit_mm: -3, positive_limit_mm: 40, index_pitch_mm: 2, index_phase_mm: 0.7}}\n"
                       "  - {name: Y, node_id: 2}\n")
    assert machine_home_sensors(cfg) == {1: HomeSensors(negative_limit_counts=-2500, positive_limit_counts=40500,
                                                        index_pitch_counts=2000, index_phase_counts=1200)}


def test_an_inverted_axis_has_its_machine_ends_on_the_other_drive_limits():
    cfg = parse_config("axes:\n  - {name: Z, node_id: 3, counts_per_mm: 100, invert: true,\n"
                       "     sim: {positive_limit_mm: 2, index_pitch_mm: 1}}\n")
    assert machine_home_sensors(cfg) == {3: HomeSensors(negative_limit_counts=-200, positive_limit_counts=None,
                                                        index_pitch_counts=100, index_phase_counts=0)}
