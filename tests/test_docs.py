"""The docs' relative links lead somewhere: every link in README.md and docs/**/*.md to a file
points to one that exists, and a link with #anchor to a heading that file has (GitHub's
anchors: lower case, punctuation dropped, spaces as hyphens, -1, -2 for repeats)."""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = sorted([ROOT / "README.md", *(ROOT / "docs").rglob("*.md")])
LINK = re.compile(r"(?<!!)\[[^\]]*\]\(([^)\s]+)\)|!\[[^\]]*\]\(([^)\s]+)\)")
LINK_TARGET = re.compile(r"\]\(([^)\s]+)\)")
FENCE = re.compile(r"^(```|~~~).*?^\1", re.S | re.M)


def slug(heading: str) -> str:
    """GitHub's anchor of a heading's text."""
    text = re.sub(r"`|\*\*|\[([^\]]*)\]\([^)]*\)", lambda m: m.group(1) or "", heading.strip().lower())
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(path: Path) -> set[str]:
    seen: Counter[str] = Counter()
    out = set()
    for line in FENCE.sub("", path.read_text(encoding="utf-8")).splitlines():
        match = re.match(r"#{1,6} (.+)", line)
        if match:
            base = slug(match.group(1))
            out.add(base if not seen[base] else f"{base}-{seen[base]}")
            seen[base] += 1
    return out


def relative_links(path: Path) -> list[str]:
    text = FENCE.sub("", path.read_text(encoding="utf-8"))
    text = re.sub(r"`[^`\n]*`", "", text)  # code spans are not links
    targets = [a or b for a, b in LINK.findall(text)]
    return [t for t in targets if not re.match(r"[a-z][a-z0-9+.-]*:", t)]  # http:, mailto:, ...


def test_the_docs_are_found():
    assert ROOT / "docs" / "benchmarks.md" in DOCS and ROOT / "README.md" in DOCS


def test_slug_follows_github():
    assert slug("`nurbsmotion check` of long CAM programs") == "nurbsmotion-check-of-long-cam-programs"
    assert slug("Soak, one hour at T = 1 ms, three axes") == "soak-one-hour-at-t--1-ms-three-axes"
    assert slug("Why 1 M set-points/s for the whole plan process") == "why-1-m-set-pointss-for-the-whole-plan-process"


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_lead_to_a_file_and_heading(doc):
    broken = []
    for target in relative_links(doc):
        name, _, anchor = target.partition("#")
        path = (doc.parent / name).resolve() if name else doc
        if not path.exists():
            broken.append(f"{target}: no file {path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}")
        elif anchor and path.suffix == ".md" and anchor not in anchors(path):
            broken.append(f"{target}: no heading #{anchor} in {path.relative_to(ROOT)}")
    assert not broken, f"{doc.relative_to(ROOT)}: " + "; ".join(broken)


def test_architecture_names_only_files_that_exist():
    """docs/architecture.md's map names modules: each `dir/name.py` must exist under
    src/nurbsmotion (or the repository), each bare `name.py` somewhere under src/nurbsmotion."""
    text = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    package = ROOT / "src" / "nurbsmotion"
    modules = {p.name for p in package.rglob("*.py")}
    missing = []
    for name in sorted(set(re.findall(r"[\w/]+\.py\b", text))):
        if "/" in name:
            if not ((package / name).exists() or (ROOT / name).exists()):
                missing.append(name)
        elif name not in modules:
            missing.append(name)
    for folder in sorted(set(re.findall(r"(?<![\w/])((?:[a-z][a-z_]*/)+)(?![\w.])", text))):
        if not (package / folder).is_dir() and not (ROOT / folder).is_dir():
            missing.append(folder)
    assert not missing, f"docs/architecture.md names what is not in the tree: {missing}"


def test_every_control_command_is_in_the_daemon_docs_at_a_glance():
    from nurbsmotion.service.protocol import COMMANDS

    text = (ROOT / "docs" / "daemon.md").read_text(encoding="utf-8")
    glance = text[text.index("## At a glance"):text.index("\n## ", text.index("## At a glance") + 1)]
    named = set(re.findall(r"`([\w]+(?:\.\w+)?)`", glance))
    named |= {f"{group}.{leaf}" for group in ("programs", "queue") for leaf in re.findall(r"`\.(\w+)`", glance)}
    assert set(COMMANDS) <= named, f"docs/daemon.md, 'At a glance' lacks {sorted(set(COMMANDS) - named)}"


def readme_docs_list() -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    start = text.index("\n## Documentation\n")
    end = text.find("\n## ", start + 1)
    return text[start:end if end != -1 else len(text)]


def test_every_doc_is_in_the_readme_docs_list():
    """A page under docs/ that README's 'Documentation' list does not link is one a reader never finds."""
    linked = {target.partition("#")[0] for target in LINK_TARGET.findall(readme_docs_list())}
    missing = [f"docs/{p.name}" for p in sorted((ROOT / "docs").glob("*.md")) if f"docs/{p.name}" not in linked]
    assert not missing, f"README.md, '## Documentation' does not link {missing}"


def test_every_log_is_linked_from_its_doc():
    """docs/NAME-log.md holds NAME.md's history: NAME.md must point to it."""
    unlinked = []
    for log in sorted((ROOT / "docs").glob("*-log.md")):
        doc = log.with_name(log.name.removesuffix("-log.md") + ".md")
        if not doc.exists() or log.name not in {t.partition("#")[0] for t in relative_links(doc)}:
            unlinked.append(f"{log.name} (from {doc.name})")
    assert not unlinked, f"history logs their doc does not link: {unlinked}"
