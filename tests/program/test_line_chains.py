"""line_chains: a program's consecutive G01 blocks as polylines with feeds and breaks."""

from __future__ import annotations

import numpy as np

from nurbsmotion.program import parse_gcode
from nurbsmotion.program.line_chains import line_chains

PROGRAM = """G21 G90
G1 X1 F600
G1 X2
G1 X3 F1200
G0 X10
G1 Y1
G1 Y2
G4 P0.5
G1 Y3
G61
G1 Y4
G1 Y5
G2 X11 Y6 I1
G1 X12
"""


def test_chains_end_at_other_blocks_and_stopping_events():
    chains = line_chains(parse_gcode(PROGRAM, "p.nc"))
    assert [(c.first_block, len(c.points) - 1) for c in chains] == [(0, 3), (4, 2), (6, 3), (10, 1)]
    np.testing.assert_allclose(chains[0].points[:, 0], [0, 1, 2, 3])
    np.testing.assert_allclose(chains[0].feeds_mm_s, [10, 10, 20])
    assert chains[1].breaks.tolist() == [False, False, True]  # the dwell after it: the block ends at rest
    assert chains[2].breaks.tolist() == [False, False, True, True]  # G61: every block ends at rest
    assert chains[2].block_of_segment(1) == 7

