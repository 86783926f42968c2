"""benchmarks/_report.py: every section a script writes exists once in docs/benchmarks.md, and a
long result goes to its detail file with a short section that links to it."""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

import pytest

from benchmarks import _report

ROOT = Path(__file__).resolve().parents[2]
WRITES = re.compile(r"write_section\(\s*\"([^\"]+)\"")


def written_sections() -> dict[str, str]:
    """Section name -> the script that writes it (the literal first argument of write_section)."""
    names = {}
    for script in sorted((ROOT / "benchmarks").glob("*.py")):
        for name in WRITES.findall(script.read_text(encoding="utf-8")):
            names[name] = script.name
    return names


def markers(kind: str) -> Counter[str]:
    return Counter(re.findall(rf"<!-- {kind} (\S+) -->", _report.DOC.read_text(encoding="utf-8")))


def test_the_scripts_write_sections():
    assert {"lookahead", "web", "demo_runs", "vs_linuxcnc"} <= set(written_sections())


@pytest.mark.parametrize("name", sorted(written_sections()))
def test_every_written_section_is_in_the_doc_once(name):
    begins, ends = markers("begin"), markers("end")
    assert begins[name] == 1 and ends[name] == 1, (
        f"{written_sections()[name]} writes section {name!r}: docs/benchmarks.md has {begins[name]} begin and "
        f"{ends[name]} end markers (want 1 each, or its --write appends a second copy)")


def test_every_marker_pair_is_whole_and_unique():
    begins, ends = markers("begin"), markers("end")
    assert begins == ends
    assert all(count == 1 for count in begins.values()), begins
    text = _report.DOC.read_text(encoding="utf-8")
    for name in begins:
        assert text.index(f"<!-- begin {name} -->") < text.index(f"<!-- end {name} -->"), name


def test_a_section_is_replaced_in_place():
    text = "# B\n\n<!-- begin a -->\nold\n<!-- end a -->\n\n<!-- begin b -->\nkept\n<!-- end b -->\n"
    new = _report.replace_section(text, "a", "<!-- begin a -->\nnew\n<!-- end a -->")
    assert new == text.replace("old", "new")
    assert _report.replace_section(text, "c", "<!-- begin c -->\nc\n<!-- end c -->").endswith(
        "<!-- begin c -->\nc\n<!-- end c -->\n")


def test_a_short_body_stays_whole_in_the_section():
    section, page = _report.render("x", "X", "Measured then.", "| a |\n|---|\n| 1 |")
    assert page is None
    assert section == "<!-- begin x -->\n## X\nMeasured then.\n\n| a |\n|---|\n| 1 |\n<!-- end x -->"


def test_a_long_body_goes_to_the_detail_file_and_the_section_shows_its_first_table():
    rows = "\n".join(f"| {i} |" for i in range(_report.SHORT_BODY_LINES + 1))
    body = f"How to read it.\n\n| a |\n|---|\n{rows}\n\nMore notes.\n\n| b |\n|---|\n| 2 |"
    section, page = _report.render("x", "X", "Measured then.", body)
    assert page is not None and body in page and "Measured then." in page
    assert "](../benchmarks.md)" in page
    assert "How to read it.\n\n| a |" in section and "More notes" not in section and "| b |" not in section
    assert "Full result: [benchmarks/x.md](benchmarks/x.md)." in section


def test_an_explicit_detail_keeps_the_given_summary():
    section, page = _report.render("x", "X", "Measured then.", "summary", detail="the long table")
    assert page is not None and "the long table" in page and "the long table" not in section
    assert "\n\nsummary\n<!-- end x -->" in section


def test_write_section_writes_the_doc_and_the_detail_file(tmp_path, monkeypatch):
    doc = tmp_path / "benchmarks.md"
    doc.write_text("# Benchmarks\n\n<!-- begin x -->\nold\n<!-- end x -->\n\nafter\n")
    monkeypatch.setattr(_report, "DOC", doc)
    monkeypatch.setattr(_report, "DETAIL_DIR", tmp_path / "benchmarks")
    _report.write_section("x", "X", "summary", "python bench_x.py", detail="| every | row |")
    text = doc.read_text()
    assert text.count("<!-- begin x -->") == 1 and "old" not in text and text.endswith("after\n")
    assert "Rerun: `python bench_x.py`. Full result: [benchmarks/x.md](benchmarks/x.md)." in text
    assert "| every | row |" in (tmp_path / "benchmarks" / "x.md").read_text()


def test_every_detail_file_belongs_to_a_written_section():
    names = set(written_sections())
    for page in _report.DETAIL_DIR.glob("*.md"):
        assert page.stem in names, f"{page.name}: no script writes section {page.stem!r}"
