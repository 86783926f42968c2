"""service.link: the daemon's master gets time-outs consistent with the configured drives."""

from __future__ import annotations

import pytest

from nurbsmotion.config import parse_config
from nurbsmotion.errors import FieldbusError
from nurbsmotion.service import link


@pytest.mark.parametrize("step_s, phase_s", [(0.5, 5.0), (1.0, 5.0), (1.5, 6.0), (3.0, 12.0)])
def test_the_enable_phase_allows_every_step_its_time_out(step_s, phase_s):
    assert link.enable_phase_timeout_s(step_s) == phase_s


def test_open_link_gives_the_master_the_step_and_phase_time_outs(monkeypatch):
    seen = {}

    class CapturingMaster:
        def __init__(self, config, **kwargs):
            seen.update(kwargs)

        def bring_up(self):
            raise FieldbusError("no bus here")

        def shutdown(self, timeout_s):
            seen["shut_down"] = True

    monkeypatch.setattr(link, "Master", CapturingMaster)
    config = parse_config("cycle_period_ms: 4\nbus: {drive_step_timeout_ms: 3000}\naxes:\n  - {name: X, node_id: 1}\n",
                          "m.yaml")
    with pytest.raises(FieldbusError):
        link.open_link(config)
    assert seen["stuck_timeout_s"] == 3.0 and seen["enable_timeout_s"] == 12.0 and seen["shut_down"]
