"""``read_program(path)``: pick the reader by file extension."""

from __future__ import annotations

from pathlib import Path

from numpy.typing import ArrayLike

from nurbsmotion.errors import InputError
from nurbsmotion.program.curve_yaml import parse_curve_yaml
from nurbsmotion.program.gcode import ReadOptions, parse_gcode
from nurbsmotion.program.model import Program
from nurbsmotion.text_files import read_text_file

GCODE_SUFFIXES = (".nc", ".ngc", ".gcode", ".tap")
YAML_SUFFIXES = (".yaml", ".yml")


def check_no_start_line(source: str, options: ReadOptions | None) -> None:
    """A YAML curve program has no lines: a start line for one is refused, not ignored."""
    if options is not None and options.start_line is not None:
        raise InputError(source, "a start line is for G-code: a YAML curve program has no lines to start from")


def read_program(path: str | Path, start_position: ArrayLike = (0.0, 0.0, 0.0), options: ReadOptions | None = None) -> Program:
    """Read a G-code (.nc .ngc .gcode .tap) or YAML curve (.yaml .yml) program.

    ``start_position`` (machine XYZ in mm) is where a G-code program starts; a YAML curve
    file starts at its first point and ignores it. ``options`` (G-code only): tool table,
    initial coordinate offsets, block delete and optional stop switches, error limit.
    """
    source = str(path)
    suffix = Path(path).suffix.lower()
    if suffix not in GCODE_SUFFIXES + YAML_SUFFIXES:
        raise InputError(source, f"unknown program type {suffix or '(no extension)'!r}: "
                                 f"expected one of {' '.join(GCODE_SUFFIXES + YAML_SUFFIXES)}")
    text = read_text_file(path)
    if suffix in YAML_SUFFIXES:
        check_no_start_line(source, options)
        return parse_curve_yaml(text, source)
    return parse_gcode(text, source, start_position, options)
