"""Write one benchmark's section of docs/benchmarks.md, with the machine, date and command.

Each benchmark owns the text between ``<!-- begin NAME -->`` and ``<!-- end NAME -->`` of
docs/benchmarks.md: a short current table. A benchmark whose full result is long (many rows of
repeats, breakdowns) passes it as ``detail``: it goes to docs/benchmarks/NAME.md, which the
section links to, and is rewritten whole on every run.
"""

from __future__ import annotations

import datetime as _dt
import os
import platform
import re
import sys
from pathlib import Path

import numpy as np

DOCS = Path(__file__).resolve().parents[1] / "docs"
DOC = DOCS / "benchmarks.md"
DETAIL_DIR = DOCS / "benchmarks"
SHORT_BODY_LINES = 12  # a longer section body goes to its detail file; docs/benchmarks.md shows its first table
SHORT_INTRO_LINES = 3  # the paragraph before that table is shown when it is at most this long


def machine_line() -> str:
    cpu = platform.processor() or "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return (f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, numpy {np.__version__}, "
            f"{platform.system()} {platform.release()}")


def section_pattern(name: str) -> re.Pattern[str]:
    """The text a section ``name`` owns in docs/benchmarks.md, markers included."""
    return re.compile(rf"<!-- begin {re.escape(name)} -->.*?<!-- end {re.escape(name)} -->", re.S)


def detail_path(name: str) -> Path:
    """docs/benchmarks/NAME.md: the full result of a benchmark whose section is its summary."""
    return DETAIL_DIR / f"{name}.md"


def replace_section(text: str, name: str, section: str) -> str:
    """``text`` with section ``name`` replaced by ``section``; appended when the doc has none."""
    pattern = section_pattern(name)
    if pattern.search(text):
        return pattern.sub(lambda _: section, text)
    return text.rstrip() + "\n\n" + section + "\n"


def first_table(body: str) -> str:
    """The first markdown table of ``body``, after the paragraph before it when that is short: what a
    long section shows in docs/benchmarks.md (its whole body goes to the detail file)."""
    blocks = [block.strip("\n") for block in body.strip().split("\n\n")]
    for i, block in enumerate(blocks):
        lines = block.splitlines()
        if lines and lines[0].startswith("|"):
            table = "\n".join(line for line in lines if line.startswith("|"))
            before = blocks[i - 1] if i else ""
            short = before and not before.startswith(("|", "#")) and len(before.splitlines()) <= SHORT_INTRO_LINES
            return f"{before}\n\n{table}" if short else table
    return blocks[0]


def render(name: str, title: str, measured: str, body: str, detail: str | None = None) -> tuple[str, str | None]:
    """Section ``name`` of docs/benchmarks.md (markers included) and the text of its detail file
    (None: none). ``measured``: the line with the date, machine and command. A ``body`` longer
    than SHORT_BODY_LINES without a ``detail`` becomes the detail, the section its first table."""
    if detail is None and len(body.strip().splitlines()) > SHORT_BODY_LINES:
        body, detail = first_table(body), body
    page, link = None, ""
    if detail is not None:
        page = (f"# {title}: full result\n\nThe summary is [benchmarks.md](../benchmarks.md), section \"{title}\"; "
                f"this file is rewritten by every run.\n\n{measured}\n\n{detail.strip()}\n")
        link = f". Full result: [benchmarks/{name}.md](benchmarks/{name}.md)."
    return f"<!-- begin {name} -->\n## {title}\n{measured}{link}\n\n{body.strip()}\n<!-- end {name} -->", page


def write_section(name: str, title: str, body: str, command: str, detail: str | None = None) -> None:
    """Replace (or append) the section ``name`` of docs/benchmarks.md; ``detail`` (the long tables;
    see render) goes whole to docs/benchmarks/NAME.md and the section links to it."""
    stamp = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    section, page = render(name, title, f"Measured {stamp} on {machine_line()}. Rerun: `{command}`", body, detail)
    if page is not None:
        detail_path(name).parent.mkdir(parents=True, exist_ok=True)
        detail_path(name).write_text(page)
    text = DOC.read_text() if DOC.exists() else "# Benchmarks\n"
    DOC.write_text(replace_section(text, name, section))
    sys.stdout.write(section + "\n")
