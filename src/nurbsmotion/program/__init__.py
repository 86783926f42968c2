"""NC programs: G-code and YAML curve readers producing a validated Program.

Public API: ``read_program(path, start_position=(0, 0, 0), options=None) -> Program``,
``parse_gcode(text, source, start_position, options=None) -> Program`` (``ReadOptions``:
tool table, initial ``CoordinateState``, switches), ``load_tool_table(path)``,
``parse_curve_yaml(text, source) -> Program``; ``ReadOptions.start_line``: start from
line N (program.gcode_start; ``Program.resume`` is the ``ResumeState`` there); errors are InputError / InputErrors.
"""

from nurbsmotion.program.coordinates import CoordinateState
from nurbsmotion.program.curve_yaml import parse_curve_yaml
from nurbsmotion.program.gcode import ReadOptions, parse_gcode
from nurbsmotion.program.model import (AXES, Block, BlockKind, CoolantMode, EventKind, Program, ProgramEvent, ResumeState,
                                       SourceRef, SpindleDirection)
from nurbsmotion.program.reader import read_program
from nurbsmotion.program.tools import Tool, ToolTable, load_tool_table, parse_tool_table

__all__ = ["AXES", "Block", "BlockKind", "CoolantMode", "CoordinateState", "EventKind", "Program", "ProgramEvent",
           "ReadOptions", "ResumeState", "SourceRef", "SpindleDirection", "Tool", "ToolTable", "load_tool_table", "parse_curve_yaml",
           "parse_gcode", "parse_tool_table", "read_program"]
