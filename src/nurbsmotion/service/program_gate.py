"""What this machine cannot do for a program, one ``file:line`` error each, before anything moves.

- M3/M4 (spindle on) without a spindle drive (``spindle: none`` or no ``spindle:`` key): a
  mill program must not "run" with its spindle stopped (issue 15, item 5).
- M7 (mist) / M8 (flood) without a coolant output in ``io.outputs`` (an output named
  ``coolant``, or ``mist``/``coolant_mist`` for M7, ``flood``/``coolant_flood`` for M8), and
  for now with one too: the daemon does not switch io outputs yet, and a program must not run
  with its coolant silently off.
- M0, M1 (with the optional-stop switch on) and M6 pass: the job holds there until
  ``resume`` (service.planner.pause_rows, the master's pause rows).

M5, M9 and S with the spindle off are no requirement and pass.
"""

from __future__ import annotations

from nurbsmotion.config import MachineConfig
from nurbsmotion.errors import InputError, InputErrors
from nurbsmotion.program import CoolantMode, EventKind, Program, ProgramEvent, SpindleDirection

COOLANT_OUTPUTS = {CoolantMode.MIST: ("coolant", "mist", "coolant_mist"),
                   CoolantMode.FLOOD: ("coolant", "flood", "coolant_flood")}
NO_OUTPUTS = "the daemon does not switch io outputs yet (io: is read but not driven)"


def coolant_output(config: MachineConfig, mode: CoolantMode) -> str | None:
    """The name of the io output that switches ``mode``, or None."""
    names = {s.name for s in config.io.outputs} if config.io is not None else set()
    return next((n for n in COOLANT_OUTPUTS[mode] if n in names), None)


def event_refusal(event: ProgramEvent, config: MachineConfig) -> str | None:
    """Why this machine cannot run ``event`` (None: it can)."""
    if event.kind is EventKind.SPINDLE and event.spindle is not SpindleDirection.OFF and config.spindle in (None, "none"):
        said = "spindle: none" if config.spindle == "none" else "no spindle: key"
        return f"{event.code} needs a spindle, and this machine has none ({said} in {config.source})"
    if event.kind is EventKind.COOLANT and event.coolant is not None and event.coolant is not CoolantMode.OFF:
        output = coolant_output(config, event.coolant)
        if output is not None:
            return f"{event.code} {event.coolant.value} coolant (output {output}): {NO_OUTPUTS}"
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
