"""nurbsmotion: NURBS toolpaths -> planned feed -> per-cycle set-points -> CiA-402 drives over CANopen."""

__version__ = "0.1.0"
