"""The submit request's start_line field and the reader options it gives (service.start_line)."""

from __future__ import annotations

import argparse
import math

import pytest

from nurbsmotion.cli.run import line_number
from nurbsmotion.config import parse_config
from nurbsmotion.errors import InputError
from nurbsmotion.program import ReadOptions
from nurbsmotion.service.start_line import start_line_field, start_line_options


@pytest.mark.parametrize("value, expected", [(None, None), (1, 1), (12, 12), (7.0, 7)])
def test_a_start_line_field_is_a_whole_line_number(value, expected):
    assert start_line_field(value) == expected


@pytest.mark.parametrize("value", [0, -3, 2.5, True])
def test_a_bad_start_line_field_is_one_line_naming_the_field(value):
    with pytest.raises(InputError) as err:
        start_line_field(value)
    assert str(err.value) == f"field 'start_line': must be a line number >= 1, got {value!r}"


def test_the_options_carry_the_line_and_the_machine_safe_z():
    config = parse_config("axes:\n  - {name: Z, node_id: 1, soft_limits_mm: [-50, 20]}\n", "m.yaml")
    options = start_line_options(ReadOptions(block_delete=False), 9, config)
    assert (options.start_line, options.safe_z_mm, options.block_delete) == (9, 19.0, False)


def test_a_machine_without_z_never_rises():
    config = parse_config("axes:\n  - {name: X, node_id: 1}\n", "m.yaml")
    assert start_line_options(ReadOptions(), 3, config).safe_z_mm == -math.inf


def test_run_start_line_option_takes_a_line_number():
    assert line_number("15") == 15
    for bad in ("0", "-2", "x", "1.5"):
        with pytest.raises(argparse.ArgumentTypeError, match="must be a line number >= 1"):
            line_number(bad)
