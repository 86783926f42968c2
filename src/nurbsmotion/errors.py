"""The one error type users see: a place and a message, printed on one line.

Every reader of outside input (G-code, curve files, YAML configuration, CLI arguments,
control-API requests, CAN frames) raises :class:`InputError` with ``where`` naming the
place: ``file:line``, ``file:line: word``, a YAML field path, or ``node 3``.
"""

from __future__ import annotations


class NurbsmotionError(Exception):
    """Base class of every error nurbsmotion raises on purpose."""


class InputError(NurbsmotionError):
    """Bad input. ``str(err)`` is the one-line message shown to the user."""

    def __init__(self, where: str, message: str) -> None:
        self.where = where
        self.message = message
        super().__init__(f"{where}: {message}" if where else message)


class Refused(InputError):
    """A control request that is well-formed but not possible now (busy, no job, in fault);
    ``where`` names the request (service.controller, service.jog)."""


class InputErrors(InputError):
    """Several independent problems found in one input; each is one line."""

    def __init__(self, errors: list[InputError]) -> None:
        if not errors:
            raise ValueError("InputErrors needs at least one error")
        self.errors = list(errors)
        first = self.errors[0]
        super().__init__(first.where, first.message)
        self.args = ("\n".join(str(e) for e in self.errors),)

    def __str__(self) -> str:
        return "\n".join(str(e) for e in self.errors)


class FieldbusError(NurbsmotionError):
    """A drive or the bus did not do what was required; names the node and the step."""
