"""Structured, quiet-by-default logging: ``level event key=value ...`` lines on stderr."""

from __future__ import annotations

import logging
import sys
from typing import Any, Callable


def kv(event: str, **fields: Any) -> str:
    """Format one structured log message: ``event key=value key2=value2``."""
    parts = [event]
    for key, value in fields.items():
        text = f"{value:.6g}" if isinstance(value, float) else str(value)
        if not text or any(c.isspace() for c in text) or '"' in text:
            text = '"' + text.replace('"', '\\"') + '"'
        parts.append(f"{key}={text}")
    return " ".join(parts)


def setup_logging(verbosity: int = 0, stream: Any = None) -> None:
    """WARNING by default, INFO with -v, DEBUG with -vv."""
    level = logging.WARNING if verbosity <= 0 else logging.INFO if verbosity == 1 else logging.DEBUG
    handler = logging.StreamHandler(stream or sys.stderr)
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s %(message)s"))
    handler.setLevel(level)  # stderr stays this quiet even where a logger is opened wider (the daemon's event stream)
    root = logging.getLogger()
    for old in list(root.handlers):
        root.removeHandler(old)
    root.addHandler(handler)
    root.setLevel(level)
    # canopen and python-can are chatty at INFO; keep them at WARNING unless -vv.
    for name in ("can", "canopen"):
        logging.getLogger(name).setLevel(logging.DEBUG if verbosity >= 2 else logging.WARNING)


def attach_handler(handler: logging.Handler, logger_name: str = "nurbsmotion") -> Callable[[], None]:
    """Add ``handler`` to the package's logger, opened to INFO if it would drop INFO records
    (the event stream and the webhooks must not depend on how verbose stderr is: its handler
    keeps its own level); returns the function that removes it again."""
    logger = logging.getLogger(logger_name)
    if not logger.isEnabledFor(logging.INFO):
        logger.setLevel(logging.INFO)
    logger.addHandler(handler)

    def detach() -> None:
        logger.removeHandler(handler)
        if not logger.handlers:
            logger.setLevel(logging.NOTSET)

    return detach


def parse_kv(message: str) -> tuple[str, dict[str, str]]:
    """The inverse of :func:`kv`: ``event key=value key2="quoted value"`` -> (event, fields).

    Values come back as the text ``kv`` wrote (numbers as ``%.6g``); a token without ``=``
    after the event is kept under its position (``_2``), so no part of a line is lost."""
    tokens: list[str] = []
    i, n = 0, len(message)
    while i < n:
        if message[i].isspace():
            i += 1
            continue
        start, quoted = i, False
        while i < n and (quoted or not message[i].isspace()):
            if message[i] == "\\" and quoted and i + 1 < n:
                i += 2
                continue
            if message[i] == '"':
                quoted = not quoted
            i += 1
        tokens.append(message[start:i])
    if not tokens:
        return "", {}
    fields: dict[str, str] = {}
    for position, token in enumerate(tokens[1:], start=1):
        key, eq, value = token.partition("=")
        if not eq or not key:
            fields[f"_{position}"] = token
            continue
        if len(value) >= 2 and value[0] == value[-1] == '"':
            value = value[1:-1].replace('\\"', '"')
        fields[key] = value
    return tokens[0], fields
