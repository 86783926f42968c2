"""``nurbsmotion offsets``: its words become the request's fields; bad words are one line."""

import argparse

import pytest

from nurbsmotion.cli.offsets import format_offsets, request_fields
from nurbsmotion.errors import InputError
from nurbsmotion.service.machine_state import MachineState, with_offset


def _args(system=None, words=(), clear=None, select=None):
    return argparse.Namespace(system=system, words=list(words), clear=clear, select=select)


def test_axis_words_become_numbers():
    assert request_fields(_args("G55", ["X10", "y-5", "Z.5"])) == {"system": "G55", "x": 10.0, "y": -5.0, "z": 0.5}
    assert request_fields(_args(clear="G92", select="G54")) == {"clear": "G92", "select": "G54"}


@pytest.mark.parametrize("words, message", [(["X"], "X: must be an axis word"), (["A5"], "A5: must be an axis word"),
                                            (["X1", "X2"], "X2: axis X is given twice"), ([], "G55: give the offset")])
def test_bad_words_are_named(words, message):
    with pytest.raises(InputError, match=message):
        request_fields(_args("G55", words))


def test_the_listing_marks_the_active_system():
    shown = format_offsets(with_offset(MachineState(), "G55", (1.5, None, None)).status())
    assert shown[0] == "active G54, tool unknown"
    assert "* G54    X0 Y0 Z0" in shown and "  G55    X1.5 Y0 Z0" in shown and "  G92    X0 Y0 Z0 (not applied)" in shown
