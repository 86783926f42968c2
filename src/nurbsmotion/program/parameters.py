"""The ``#`` parameters of a running G-code program (LinuxCNC "Parameters" §5).

- Numbered ``#1`` ... ``#5602``: read as 0 until set. ``#1``-``#30`` are local to a
  subroutine call (the call's arguments; the caller's values come back on return).
- Named ``#<name>``: local to the subroutine level that set them; ``#<_name>`` is global.
  Reading a name never set is an error (LinuxCNC does the same). Names are lower case and
  spaces inside them do not count.
- System parameters (work offsets #5221..., the current position #5420..., ``#<_x>``,
  ``#<_metric>``, ...) come from the interpreter's state through ``system``; writing them
  is refused with the G code that sets them.
- Assignments of one line take effect together after the line is read (RS274NGC §3.3.1):
  ``stage`` collects them and ``commit`` applies them.
"""

from __future__ import annotations

from typing import Callable

from nurbsmotion.program.expressions import ExpressionError

LOCAL_NUMBERED = range(1, 31)
SYSTEM_FIRST = 5161  # numbered parameters from here on belong to the interpreter's state

SystemLookup = Callable[[int | str], float | None]


class ParameterStore:
    """Numbered and named parameters with subroutine scopes."""

    def __init__(self, system: SystemLookup) -> None:
        self.system = system
        self.numbered: dict[int, float] = {}
        self.globals: dict[str, float] = {}
        self.scopes: list[dict[str, float]] = [{}]
        self.saved_locals: list[dict[int, float]] = []
        self.pending: list[tuple[int | str, float]] = []

    def get(self, key: int | str) -> float:
        value = self.system(key)
        if value is not None:
            return value
        if isinstance(key, int):
            return self.numbered.get(key, 0.0)
        table = self.globals if key.startswith("_") else self.scopes[-1]
        if key not in table:
            raise ExpressionError(f"parameter #<{key}> is not defined")
        return table[key]

    def exists(self, key: int | str) -> bool:
        if isinstance(key, int):
            return True
        if self.system(key) is not None:
            return True
        return key in (self.globals if key.startswith("_") else self.scopes[-1])

    def stage(self, key: int | str, value: float) -> None:
        if isinstance(key, int) and key >= SYSTEM_FIRST and self.system(key) is not None:
            raise ExpressionError(f"#{key} is a system parameter: set it with the G code that owns it (G10, G28.1, G92...)")
        if isinstance(key, str) and key.startswith("_") and self.system(key) is not None:
            raise ExpressionError(f"#<{key}> is read-only")
        self.pending.append((key, value))

    def commit(self) -> None:
        for key, value in self.pending:
            self.set_now(key, value)
        self.pending.clear()

    def discard(self) -> None:
        self.pending.clear()

    def set_now(self, key: int | str, value: float) -> None:
        if isinstance(key, int):
            self.numbered[key] = value
        elif key.startswith("_"):
            self.globals[key] = value
        else:
            self.scopes[-1][key] = value

    def enter_call(self, args: list[float]) -> None:
        """A subroutine call: save #1-#30, set them to the arguments, open a named scope."""
        self.saved_locals.append({n: self.numbered[n] for n in LOCAL_NUMBERED if n in self.numbered})
        for n in LOCAL_NUMBERED:
            self.numbered.pop(n, None)
        for n, value in zip(LOCAL_NUMBERED, args):
            self.numbered[n] = value
        self.scopes.append({})

    def leave_call(self) -> None:
        for n in LOCAL_NUMBERED:
            self.numbered.pop(n, None)
        self.numbered.update(self.saved_locals.pop())
        self.scopes.pop()
