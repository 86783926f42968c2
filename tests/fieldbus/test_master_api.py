"""Master checks its inputs before touching the bus: bad arrays, wrong state, overload."""

import numpy as np
import pytest

from nurbsmotion.config import parse_config
from nurbsmotion.errors import FieldbusError, InputError
from nurbsmotion.fieldbus import Master


def _config(period_ms: float = 4, n_axes: int = 2):
    axes = "".join(f"  - {{name: A{i}, node_id: {i + 1}}}\n" for i in range(n_axes))
    return parse_config(f"cycle_period_ms: {period_ms}\naxes:\n{axes}", "m.yaml")


def test_overloaded_bus_is_refused_at_construction():
    with pytest.raises(InputError, match="bus load .* exceeds 80%"):
        Master(_config(period_ms=1, n_axes=6))


@pytest.mark.parametrize("counts, message", [
    (np.zeros((5, 3), dtype=np.int32), r"shape \(N >= 1, 2\)"),
    (np.zeros((0, 2), dtype=np.int32), r"shape \(N >= 1, 2\)"),
    (np.zeros((5, 2)), "must be integers"),
    (np.full((5, 2), 2**40), "int32 range"),
])
def test_bad_set_point_arrays_are_refused(counts, message):
    with pytest.raises(InputError, match=message):
        Master(_config()).stream(counts)


def test_streaming_before_bring_up_is_refused():
    with pytest.raises(FieldbusError, match="call bring_up"):
        Master(_config()).stream(np.zeros((5, 2), dtype=np.int32))


def test_unknown_options_are_refused():
    with pytest.raises(InputError, match="sync_source"):
        Master(_config(), sync_source="magic")
    with pytest.raises(InputError, match="gc_mode"):
        Master(_config(), gc_mode="off")
