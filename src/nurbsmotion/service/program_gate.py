"""What this machine cannot do for a program, one ``file:line`` error each, before anything moves.

- M3/M4 (spindle on) without a spindle drive (``spindle: none`` or no ``spindle:`` key): a
  mill program must not "run" with its spindle stopped (issue 15, item 5).
- With a spindle drive: M3/M4 without any S before (``M3 needs S``), an S above the
  spindle's ``max_rpm``, and G96 constant surface speed (the drive takes rpm only).
- M7 (mist) / M8 (flood) without a coolant output in ``io.outputs`` (an output named
  ``coolant``, or ``mist``/``coolant_mist`` for M7, ``flood``/``coolant_flood`` for M8): a
  program must not run with its coolant silently off. With one, the daemon switches it
  (service.machine_io).
- M62-M65 P (LinuxCNC digital outputs) without an ``io.outputs`` entry at bit P.
- M0, M1 (with the optional-stop switch on) and M6 pass: the job holds there until
  ``resume`` (service.planner.pause_rows, the master's pause rows).

M5, M9 and S with the spindle off (no M3/M4 ever) are no requirement and pass.
"""

from __future__ import annotations

from nurbsmotion.config import MachineConfig
from nurbsmotion.errors import InputError, InputErrors
from nurbsmotion.program import CoolantMode, EventKind, Program, ProgramEvent, SpindleDirection
from nurbsmotion.config.spindle import SpindleConfig

COOLANT_OUTPUTS = {CoolantMode.MIST: ("coolant", "mist", "coolant_mist"),
                   CoolantMode.FLOOD: ("coolant", "flood", "coolant_flood")}


def coolant_output(config: MachineConfig, mode: CoolantMode) -> str | None:
    """The name of the io output that switches ``mode``, or None."""
    names = {s.name for s in config.io.outputs} if config.io is not None else set()
    return next((n for n in COOLANT_OUTPUTS[mode] if n in names), None)


def spindle_refusal(event: ProgramEvent, config: MachineConfig) -> str | None:
    """Why the configured spindle cannot run this M3/M4/S event (None: it can)."""
    if not isinstance(config.spindle, SpindleConfig):  # None or 'none'
        said = "spindle: none" if config.spindle == "none" else "no spindle: key"
        return f"{event.code} needs a spindle, and this machine has none ({said} in {config.source})"
    rpm, max_rpm = event.spindle_rpm or 0.0, config.spindle.max_rpm
    if event.constant_surface_speed:
        return f"{event.code} under G96 (constant surface speed): the spindle drive takes rpm only; use G97"
    if rpm <= 0.0:
        return f"{event.code} needs S (the spindle speed in rpm): no S > 0 before it"
    if rpm > max_rpm:
        return f"S{rpm:g} is above the spindle's max_rpm {max_rpm:g} ({config.where('spindle.max_rpm')})"
    return None


def output_at_bit(config: MachineConfig, bit: int) -> str | None:
    """The name of the io output at ``bit`` (M62-M65 P), or None."""
    return next((s.name for s in config.io.outputs if s.bit == bit), None) if config.io is not None else None


def event_refusal(event: ProgramEvent, config: MachineConfig) -> str | None:
    """Why this machine cannot run ``event`` (None: it can)."""
    if event.kind is EventKind.OUTPUT and event.output is not None and output_at_bit(config, event.output) is None:
        where = f"io.outputs in {config.source}" if config.io is not None else f"no io: node in {config.source}"
        return f"{event.code} P{event.output}: this machine has no digital output {event.output} ({where})"
    if event.kind is EventKind.SPINDLE and event.spindle is not SpindleDirection.OFF:
        return spindle_refusal(event, config)
    if event.kind is EventKind.COOLANT and event.coolant is not None and event.coolant is not CoolantMode.OFF:
        if coolant_output(config, event.coolant) is not None:
            return None
        names = COOLANT_OUTPUTS[event.coolant]
        wanted = f"{', '.join(names[:-1])} or {names[-1]}"
        return (f"{event.code} needs {event.coolant.value} coolant, and this machine has no output named "
                f"{wanted} (io.outputs in {config.source})")
    return None


def check_machine_can_run(program: Program, config: MachineConfig) -> None:
    """InputErrors, one per event this machine cannot run, in program order."""
    errors = [InputError(str(e.source), why) for e in program.events if (why := event_refusal(e, config)) is not None]
    if len(errors) == 1:
        raise errors[0]
    if errors:
        raise InputErrors(errors)
