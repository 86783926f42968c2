"""Feed planning and interpolation: Program + PlanLimits -> Trajectory (set-points per cycle).

Algorithms are selected by name. Each algorithm module exposes ``ALGORITHMS``, a dict of
name -> function(program, limits) -> Trajectory; this package only knows the module names.
"""

from __future__ import annotations

import importlib
from typing import Callable

from nurbsmotion.errors import InputError
from nurbsmotion.planning.limits import PlanLimits
from nurbsmotion.planning.trajectory import Trajectory
from nurbsmotion.program import Program

PlanFunction = Callable[[Program, PlanLimits], Trajectory]

# algorithm name -> module that implements it
ALGORITHM_MODULES: dict[str, str] = {
    "taylor1": "nurbsmotion.planning.interpolators",
    "taylor2": "nurbsmotion.planning.interpolators",
    "wang": "nurbsmotion.planning.interpolators",
    "zhang": "nurbsmotion.planning.interpolators",
    "lookahead": "nurbsmotion.planning.lookahead",
}
DEFAULT_ALGORITHM = "lookahead"


def algorithm(name: str) -> PlanFunction:
    """The planning function registered under ``name``; InputError for unknown names."""
    if name not in ALGORITHM_MODULES:
        raise InputError("algorithm", f"unknown algorithm {name!r}; choose one of {', '.join(ALGORITHM_MODULES)}")
    module = importlib.import_module(ALGORITHM_MODULES[name])
    return module.ALGORITHMS[name]


def plan(program: Program, limits: PlanLimits, algorithm_name: str = DEFAULT_ALGORITHM) -> Trajectory:
    """Plan the whole program with the named algorithm."""
    return algorithm(algorithm_name)(program, limits)


__all__ = ["ALGORITHM_MODULES", "DEFAULT_ALGORITHM", "PlanLimits", "Trajectory", "algorithm", "plan"]
