"""The configuration a job ran with, as its record keeps it (config.json), and as the
checked-program store fingerprints it. Apart from service.records so that the control
commands, which read records, do not import the configuration loader."""

from __future__ import annotations

import dataclasses
from enum import Enum
from typing import Any

from nurbsmotion.config import MachineConfig
from nurbsmotion.config.spindle import SpindleConfig


def config_dict(config: MachineConfig, offset_counts: Any = None) -> dict[str, Any]:
    """The configuration a job ran with, every default filled in (config.json of a record);
    ``offset_counts``: the axis map's offsets in force (homing moves them: service.homing)."""
    offsets = [a.offset_counts for a in config.axes] if offset_counts is None else [int(o) for o in offset_counts]
    plain_axes = tuple(dataclasses.replace(a, od=None, offset_counts=o)  # the EDS as read: not a value
                       for a, o in zip(config.axes, offsets))
    spindle = dataclasses.replace(config.spindle, od=None) if isinstance(config.spindle, SpindleConfig) \
        else config.spindle
    out = dataclasses.asdict(dataclasses.replace(config, axes=plain_axes, spindle=spindle), dict_factory=plain_dict)
    out.pop("lines", None)
    if isinstance(out["spindle"], dict):
        out["spindle"].pop("od", None)
    for axis in out["axes"]:
        axis.pop("od", None)
    return out


def plain_dict(items: list[tuple[str, Any]]) -> dict[str, Any]:
    """asdict's mapping with enum members as their YAML words (``web.cpus: auto``)."""
    return {key: value.value if isinstance(value, Enum) else value for key, value in items}
