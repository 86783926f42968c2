"""The simulated drives' limit switches and index pulses from a configuration's ``axes[i].sim``
sections (machine mm) as raw counts (:class:`HomeSensors`, counts at power-on).

An axis maps mm to counts as ``counts = sign · mm · counts_per_mm + offset_counts`` (sign -1
when ``invert``; nurbsmotion.axes.AxisMap); the simulated drive starts at 0 raw counts, so a
switch at ``x`` mm sits at that many raw counts. A drive's negative limit switch is the one
at its lower counts: on an inverted axis the machine's negative end is the drive's positive
limit, so the two swap. Read by attribute, as SimNetwork.for_machine reads the machine.
"""

from __future__ import annotations

from typing import Any

from nurbsmotion.sim.homing import HomeSensors


def raw_counts(axis: Any, mm: float) -> float:
    """Raw drive counts at machine position ``mm`` (before any homing)."""
    sign = -1.0 if axis.invert else 1.0
    return sign * mm * axis.counts_per_mm + axis.offset_counts


def axis_home_sensors(axis: Any) -> HomeSensors:
    """One axis' ``sim`` section (negative/positive_limit_mm, index_pitch/phase_mm) as HomeSensors."""
    sim = axis.sim
    ends = [None if mm is None else raw_counts(axis, mm) for mm in (sim.negative_limit_mm, sim.positive_limit_mm)]
    negative, positive = reversed(ends) if axis.invert else ends
    pitch = None if sim.index_pitch_mm is None else sim.index_pitch_mm * axis.counts_per_mm
    return HomeSensors(negative_limit_counts=negative, positive_limit_counts=positive, index_pitch_counts=pitch,
                       index_phase_counts=raw_counts(axis, sim.index_phase_mm))


def machine_home_sensors(machine: Any) -> dict[int, HomeSensors]:
    """{node id: HomeSensors} of every axis with a ``sim`` section."""
    return {axis.node_id: axis_home_sensors(axis) for axis in machine.axes if getattr(axis, "sim", None) is not None}
