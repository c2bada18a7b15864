"""The README and docs/: every relative link resolves (file and heading), the README stays a first
screen, and the code carries no journal (issue numbers, session words, files that no longer exist)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
CODE_BLOCK = re.compile(r"```.*?```", re.S)
CODE_DIRS = ("robots", "lab", "app", "benchmarks", "examples", "tests")


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[`*_]", "", heading.strip().lower())
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(page: Path) -> set[str]:
    text = CODE_BLOCK.sub("", page.read_text())
    return {slug(m.group(1)) for m in re.finditer(r"^#{1,6}\s+(.*)$", text, re.M)}


def links(page: Path) -> list[str]:
    return LINK.findall(CODE_BLOCK.sub("", page.read_text()))


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves_to_a_file_and_heading(page):
    broken = []
    for target in links(page):
        if re.match(r"[a-z]+:", target):  # http:, https:, mailto:
            continue
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            broken.append(f"{target}: no file {dest.relative_to(ROOT) if dest.is_relative_to(ROOT) else dest}")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            broken.append(f"{target}: no heading #{anchor} in {dest.relative_to(ROOT)}")
    assert not broken, f"{page.relative_to(ROOT)} has broken links:\n" + "\n".join(broken)


def test_the_readme_is_a_first_screen_and_links_every_guide():
    readme = (ROOT / "README.md").read_text()
    assert len(readme.splitlines()) <= 200
    assert "make app" in readme and "make test" in readme
    reached = {(ROOT / t.partition("#")[0]).resolve() for t in links(ROOT / "README.md") if not re.match(r"[a-z]+:", t)}
    index = ROOT / "docs" / "index.md"
    reached |= {(index.parent / t.partition("#")[0]).resolve() for t in links(index) if not re.match(r"[a-z]+:", t)}
    orphans = [p.relative_to(ROOT) for p in PAGES[1:] if p.resolve() not in reached and p.parent.name != "lessons"]
    assert not orphans, f"pages neither the README nor docs/index.md links: {orphans}"


def test_the_slug_follows_githubs_rule():
    assert slug("The paper's claims, tested") == "the-papers-claims-tested"
    assert slug("2026-12-02: real arms, inputs that know the shoulder (\"sphere\")") == (
        "2026-12-02-real-arms-inputs-that-know-the-shoulder-sphere")


JOURNAL = re.compile(r"\bissues? \d+\b|\bthe issue\b|\b(?:evening|afternoon|morning) session\b|\bthis session\b|"
                     r"lab/pipes\.py|lab/recording\.py|lab/recording_writer\.py|lab/replay\.py|README")


def test_the_code_carries_no_journal():
    """Docstrings state the rule and point to docs/; measurements and their history live there."""
    found = []
    for folder in CODE_DIRS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            if path.name == "test_docs.py":
                continue
            for n, line in enumerate(path.read_text().splitlines(), 1):
                if JOURNAL.search(line):
                    found.append(f"{path.relative_to(ROOT)}:{n}: {line.strip()[:100]}")
    assert not found, "journal in code (move it to docs/):\n" + "\n".join(found)
