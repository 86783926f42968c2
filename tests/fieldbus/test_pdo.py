"""PDO encodings: mapping entries and the 0x60C2 period (value·10^exponent)."""

import pytest

from nurbsmotion.fieldbus.pdo import interpolation_period, mapping_entry


@pytest.mark.parametrize("period_s, expected", [(0.004, (4, -3)), (0.0025, (25, -4)), (0.001, (1, -3))])
def test_interpolation_period_value_and_exponent(period_s, expected):
    assert interpolation_period(period_s) == expected


def test_interpolation_period_scales_to_a_fixed_exponent():
    assert interpolation_period(0.004, -4) == (40, -4)
    with pytest.raises(ValueError, match="fixed exponent -6"):
        interpolation_period(0.004, -6)  # 4000 does not fit 0x60C2:01 (u8)


def test_mapping_entry_packs_index_subindex_and_bits():
    assert mapping_entry(0x60C1, 1, 32) == 0x60C10120
