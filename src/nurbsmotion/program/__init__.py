"""NC programs: G-code and YAML curve readers producing a validated Program."""

from nurbsmotion.program.model import AXES, Block, BlockKind, Program, SourceRef

__all__ = ["AXES", "Block", "BlockKind", "Program", "SourceRef"]
