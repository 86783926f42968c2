"""NC programs: G-code and YAML curve readers producing a validated Program.

Public API: ``read_program(path, start_position=(0, 0, 0)) -> Program``,
``parse_gcode(text, source, start_position) -> Program``,
``parse_curve_yaml(text, source) -> Program``; errors are InputError / InputErrors.
"""

from nurbsmotion.program.curve_yaml import parse_curve_yaml
from nurbsmotion.program.gcode import parse_gcode
from nurbsmotion.program.model import AXES, Block, BlockKind, Program, SourceRef
from nurbsmotion.program.reader import read_program

__all__ = ["AXES", "Block", "BlockKind", "Program", "SourceRef", "parse_curve_yaml", "parse_gcode", "read_program"]
