"""Homing against every real vendor EDS/DCF in tests/data/eds (SOURCES.md): the plan the
file allows (which objects, how the home offset is applied) or the one-line refusal at load
naming file:line, axis, node, EDS and object."""

from __future__ import annotations

from pathlib import Path

import pytest

from nurbsmotion.config import parse_config
from nurbsmotion.errors import InputError
from nurbsmotion.fieldbus import Master
from nurbsmotion.fieldbus.homing_check import OffsetRoute, offered_homing, plan_homing
from nurbsmotion.config.homing import HERE, HomingConfig

EDS_DIR = Path(__file__).resolve().parents[1] / "data" / "eds"
MOVING = "{method: 17, speed_search_mm_s: 20, speed_zero_mm_s: 2, accel_mm_s2: 200, offset_mm: -20}"

# file -> (a mode bring-up accepts, None if neither; the route of MOVING's offset, or a fragment of the refusal)
EXPECTED: dict[str, tuple[str | None, OffsetRoute | str]] = {
    "elmo_Elmo.eds": ("csp", OffsetRoute.DRIVE),
    "elmo_Whistle_Gold_V002.dcf": ("csp", OffsetRoute.DRIVE),
    "faulhaber_605.3150.73-A-EK-2-60.eds": (None, OffsetRoute.DRIVE),
    "maxon_epos2_347717.eds": ("csp", OffsetRoute.DRIVE),
    "maxon_epos4_50_15_node1.dcf": ("csp", OffsetRoute.MASTER),  # no 0x607C
    "nanotec_C5-E-2-09.eds": ("csp", OffsetRoute.DRIVE),
    "nanotec_CL3-E-2-0F.eds": ("ip", OffsetRoute.DRIVE),
    "pilz_prbt.eds": ("ip", "'s 0x6502:00 (supported drive modes) = 0x00000043 lacks bit 5 (homing mode), so "
                            "homing method 17 is not possible; use method: here"),
    "schunk_PRL120.eds": ("ip", " has no 0x6098:00 (homing method), needed for homing method 17; use method: here"),
    "technosoft_ISD860.eds": ("ip", OffsetRoute.DRIVE),
    "technosoft_iPOS.eds": ("ip", OffsetRoute.DRIVE),
    "zeroerr_eDriver_V1.5.eds": ("csp", "'s 0x6502:00 (supported drive modes) = 0x0000038D lacks bit 5 (homing "
                                        "mode), so homing method 17 is not possible; use method: here"),
}


def machine(eds: str, homing: str = MOVING, mode: str = "csp", extra: str = ""):
    text = (f"cycle_period_ms: 4\nbus: {{interface: virtual, channel: unused}}\n"
            f"monitoring: {{heartbeat_producer_ms: 50, heartbeat_consumer_ms: 600}}\naxes:\n"
            f"  - name: X\n    node_id: 1\n    mode: {mode}\n    counts_per_mm: 1000\n    eds: {EDS_DIR / eds}\n"
            f"    homing: {homing}\n{extra}")
    return parse_config(text, "corpus.yaml")


def test_every_corpus_file_has_an_expectation():
    files = sorted(p.name for p in EDS_DIR.iterdir() if p.suffix.lower() in (".eds", ".dcf"))
    assert sorted(EXPECTED) == files


@pytest.mark.parametrize("eds", sorted(EXPECTED))
def test_moving_homing_plan_or_one_line_refusal(eds):
    mode, expected = EXPECTED[eds]
    config = machine(eds, mode=mode or "csp")
    if isinstance(expected, OffsetRoute):
        homing = plan_homing(config, 0)
        assert homing is not None and homing.route is expected
        writes = [(w.index, w.subindex, w.value) for w in homing.plan.writes]
        # 20 mm/s, 2 mm/s, 200 mm/s² at 1000 counts/mm (speed units: counts/s, the default)
        assert writes[:4] == [(0x6098, 0, 17), (0x6099, 1, 20_000), (0x6099, 2, 2000), (0x609A, 0, 200_000)]
        assert writes[-1] == (0x6060, 0, 6) and homing.plan.mode_check == 6
        if expected is OffsetRoute.DRIVE:  # CiA 402: the home reads -0x607C = -20 mm · 1000
            assert writes[4] == (0x607C, 0, 20_000) and homing.offset_counts_after == 0
        else:  # the drive's home reads 0; the axis map reads it -20 mm: mm = (counts - 20000)/1000
            assert len(writes) == 5 and homing.offset_counts_after == 20_000
        return
    with pytest.raises(InputError) as info:
        plan_homing(config, 0)
    assert str(info.value) == f"corpus.yaml:10: axes[0].homing.method (X, node 1): {eds}{expected}"


@pytest.mark.parametrize("eds", sorted(e for e, (mode, route) in EXPECTED.items() if mode and isinstance(route, str)))
def test_a_refused_homing_stops_the_master_before_the_bus(eds):
    mode, expected = EXPECTED[eds]
    with pytest.raises(InputError) as info:
        Master(machine(eds, mode=mode))  # refused before any bus is opened
    text = str(info.value)
    assert "\n" not in text and text.endswith(f"{eds}{expected}")


@pytest.mark.parametrize("eds", sorted(e for e, (_, route) in EXPECTED.items() if isinstance(route, OffsetRoute)))
def test_a_zero_offset_writes_no_offset_object(eds):
    homing = plan_homing(machine(eds, "{method: 34, speed_search_mm_s: 20, speed_zero_mm_s: 2, accel_mm_s2: 200}"), 0)
    assert homing is not None and homing.route is OffsetRoute.NONE and homing.offset_counts_after == 0
    assert [w.index for w in homing.plan.writes] == [0x6098, 0x6099, 0x6099, 0x609A, 0x6060]


def test_a_method_beyond_the_eds_range_is_refused_at_its_line():
    with pytest.raises(InputError) as info:
        plan_homing(machine("elmo_Elmo.eds", "{method: 37}"), 0)
    assert str(info.value) == ("corpus.yaml:10: axes[0].homing.method (X, node 1): elmo_Elmo.eds's 0x6098:00 "
                               "(homing_method) allows -128..35 (LowLimit/HighLimit), not 37, needed for homing "
                               "method 37; use method: here")


def test_a_speed_beyond_the_eds_limit_names_the_speed():
    with pytest.raises(InputError) as info:  # EPOS4: 0x6099:01 1..50000
        plan_homing(machine("maxon_epos4_50_15_node1.dcf", MOVING.replace("speed_search_mm_s: 20", "speed_search_mm_s: 60")), 0)
    assert str(info.value).startswith("corpus.yaml:10: axes[0].homing.speed_search_mm_s (X, node 1): "
                                      "maxon_epos4_50_15_node1.dcf's 0x6099:01 (Speed for switch search) allows "
                                      "1..50000 (LowLimit/HighLimit), not 60000")


def test_the_vendor_object_named_takes_the_offset():
    homing = "{method: 35, offset_mm: -20, home_offset_object: 0x30B0, home_offset_sign: 1}"
    plan = plan_homing(machine("maxon_epos4_50_15_node1.dcf", homing), 0)
    assert plan is not None and plan.route is OffsetRoute.VENDOR and plan.offset_counts_after == 0
    # EPOS4 0x30B0 "home position": the home reads the value written, -20 mm · 1000
    assert [(w.index, w.value) for w in plan.plan.writes] == [(0x6098, 35), (0x30B0, -20_000), (0x6060, 6)]
    assert plan.describe()[1] == "  home    offset: vendor object 0x30B0"


def test_a_vendor_object_the_eds_lacks_is_refused_at_its_line():
    homing = "\n      method: 35\n      offset_mm: 1\n      home_offset_object: 0x30B0\n      home_offset_sign: 1"
    with pytest.raises(InputError) as info:
        plan_homing(machine("elmo_Elmo.eds", homing), 0)
    assert str(info.value) == ("corpus.yaml:13: axes[0].homing.home_offset_object (X, node 1): elmo_Elmo.eds has no "
                               "0x30B0:00 to take the home offset")


@pytest.mark.parametrize("eds", sorted(EXPECTED))
def test_the_demo_homes_with_what_the_eds_offers(eds):
    _, expected = EXPECTED[eds]
    axis = machine(eds).axes[0]
    wanted = axis.homing
    offered = offered_homing(axis, wanted)
    if isinstance(expected, OffsetRoute):
        assert offered == wanted
    else:
        assert offered == HomingConfig(method=HERE, offset_mm=-20)
