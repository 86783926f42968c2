"""G64 Q: the short-segment smoothing tolerance of the following blocks (docs/programs.md)."""

import pytest

from nurbsmotion.program import parse_gcode


@pytest.mark.parametrize(("text", "expected"), [
    ("G21 G1 X1 F600\n", None),  # no G64: the machine's switch decides
    ("G21 G64 P0.01\nG1 X1 F600\n", None),  # P alone: Q not given
    ("G21 G64 P0.01 Q0.005\nG1 X1 F600\n", 0.005),
    ("G21 G64 P0.01 Q0\nG1 X1 F600\n", 0.0),  # Q0: smoothing off
    ("G20 G64 P0.001 Q0.002\nG1 X1 F6\n", 0.002 * 25.4),  # program units
])
def test_g64_q_is_the_smoothing_tolerance_of_the_following_blocks(text: str, expected: float | None) -> None:
    block = parse_gcode(text, "t.nc").blocks[-1]
    if expected is None:
        assert block.smoothing_tolerance_mm is None
    else:
        assert block.smoothing_tolerance_mm == pytest.approx(expected)


def test_a_later_g64_without_q_gives_the_machine_its_switch_back() -> None:
    blocks = parse_gcode("G21 G64 P0.01 Q0\nG1 X1 F600\nG64 P0.02\nG1 X2\n", "t.nc").blocks
    assert [b.smoothing_tolerance_mm for b in blocks] == [0.0, None]
