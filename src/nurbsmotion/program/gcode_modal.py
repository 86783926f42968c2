"""M70-M73: save and restore the modal state (LinuxCNC "M-codes", M70 Save Modal State).

M70 saves at the current call level, M72 restores what M70 saved there, M71 forgets it,
M73 saves and restores automatically when the current subroutine returns (endsub or
return). Saved: units, plane, distance and arc distance modes, feed, coordinate system,
path control (G61/G64 P), spindle mode, speed and direction, coolant. Restoring a spindle
or coolant state that differs makes the SPINDLE / COOLANT events that change it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from nurbsmotion.errors import InputError
from nurbsmotion.program.coordinates import Offsets
from nurbsmotion.program.gcode_line import GcodeLine
from nurbsmotion.program.gcode_words import Word
from nurbsmotion.program.model import CoolantMode, EventKind, SpindleDirection


@dataclass(frozen=True)
class ModalSnapshot:
    mm_per_unit: float
    plane: int
    absolute: bool
    arc_absolute: bool
    feed_mm_s: float | None
    active_system: int
    exact_stop_mode: bool
    blend_tolerance_mm: float | None
    smoothing_tolerance_mm: float | None
    constant_surface_speed: bool
    spindle: SpindleDirection
    spindle_rpm: float
    coolant: frozenset[CoolantMode]


class ModalStateCommands:
    """The M70-M73 part of the G-code reader (mixed into GcodeParser)."""

    mm_per_unit: float
    plane: int
    absolute: bool
    arc_absolute: bool
    feed_mm_s: float | None
    offsets: Offsets
    exact_stop_mode: bool
    blend_tolerance_mm: float | None
    smoothing_tolerance_mm: float | None
    constant_surface_speed: bool
    spindle: SpindleDirection
    spindle_rpm: float
    coolant: set[CoolantMode]
    saved_states: list[ModalSnapshot | None]  # per call level, the top level first
    add_event: Callable[..., None]  # provided by GcodeParser

    def snapshot(self) -> ModalSnapshot:
        return ModalSnapshot(self.mm_per_unit, self.plane, self.absolute, self.arc_absolute, self.feed_mm_s,
                             self.offsets.active, self.exact_stop_mode, self.blend_tolerance_mm, self.smoothing_tolerance_mm,
                             self.constant_surface_speed, self.spindle, self.spindle_rpm, frozenset(self.coolant))

    def restore(self, line: GcodeLine, code: str, s: ModalSnapshot) -> None:
        self.mm_per_unit, self.plane, self.absolute, self.arc_absolute = s.mm_per_unit, s.plane, s.absolute, s.arc_absolute
        self.feed_mm_s, self.offsets.active = s.feed_mm_s, s.active_system
        self.exact_stop_mode, self.blend_tolerance_mm = s.exact_stop_mode, s.blend_tolerance_mm
        self.smoothing_tolerance_mm = s.smoothing_tolerance_mm
        self.constant_surface_speed = s.constant_surface_speed
        if (s.spindle, s.spindle_rpm) != (self.spindle, self.spindle_rpm):
            self.spindle, self.spindle_rpm = s.spindle, s.spindle_rpm
            self.add_event(line, EventKind.SPINDLE, code, spindle=s.spindle,
                           spindle_rpm=None if s.spindle is SpindleDirection.OFF else s.spindle_rpm,
                           constant_surface_speed=s.constant_surface_speed)
        if s.coolant != frozenset(self.coolant):
            self.coolant = set(s.coolant)
            for mode in sorted(s.coolant, key=lambda m: m.value) or [CoolantMode.OFF]:
                self.add_event(line, EventKind.COOLANT, code, coolant=mode)

    def apply_modal_state(self, line: GcodeLine, m: Word | None, autorestore: list[ModalSnapshot | None]) -> None:
        """M70/M71/M72/M73 of this line; ``autorestore`` is the current call's slot for M73."""
        if m is None:
            return
        code = int(m.value)
        if code in (70, 73):
            self.saved_states[-1] = self.snapshot()
            if code == 73:
                if len(self.saved_states) == 1:
                    raise InputError(line.at(m), "M73 outside a subroutine: use M70 and M72")
                autorestore[0] = self.saved_states[-1]
        elif code == 71:
            self.saved_states[-1] = None
        else:
            saved = self.saved_states[-1]
            if saved is None:
                raise InputError(line.at(m), "M72 without a state saved by M70 at this call level")
            self.restore(line, m.text, saved)
