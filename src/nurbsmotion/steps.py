"""Work written as a generator: it yields between its parts and returns its result.

A leaf module (imports nothing of the package): the cycle thread's slack runs such steps
(fieldbus.cycle_slack), and the forked planner's chunks are drained the same way (cli._forked).
"""

from __future__ import annotations

from typing import Callable, Generator, TypeVar

Item = TypeVar("Item")
Result = TypeVar("Result")
Steps = Generator[object, None, Result]  # yields between its parts, returns its result


def drained(items: Generator[Item, None, Result], each: Callable[[Item], None]) -> Result:
    """Hand every item of ``items`` to ``each`` in order; the generator's return value. The
    generator is closed on any error (a forked child is then ended)."""
    try:
        while True:
            try:
                item = next(items)
            except StopIteration as end:
                return end.value
            each(item)
    finally:
        items.close()
