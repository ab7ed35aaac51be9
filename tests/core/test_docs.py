"""The README stays a five-minute read, and every link in it and in docs/ leads somewhere.

The README is for users; everything longer lives in ``docs/`` (issue #27). A link to a missing
file, or to a heading that was renamed, is caught here rather than by a reader.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from support import REPO_ROOT

README = REPO_ROOT / "README.md"
DOCS = REPO_ROOT / "docs"
README_MAX_BYTES = 12_000

FENCED_BLOCK = re.compile(r"^```.*?^```", re.MULTILINE | re.DOTALL)
INLINE_CODE = re.compile(r"`[^`\n]*`")
MARKDOWN_LINK = re.compile(r"\[[^\]\n]*\]\(([^)\s]+)\)")
HEADING = re.compile(r"^#{1,6}\s+(.+?)\s*$", re.MULTILINE)


def markdown_pages() -> list[Path]:
    return [README, *sorted(DOCS.glob("*.md")), REPO_ROOT / "bags" / "README.md"]


def prose(text: str) -> str:
    """The text without code, where brackets and parentheses are not links."""
    return INLINE_CODE.sub("", FENCED_BLOCK.sub("", text))


def relative_links(page: Path) -> list[str]:
    links = MARKDOWN_LINK.findall(prose(page.read_text()))
    return [link for link in links if not re.match(r"[a-z]+:", link)]


def heading_anchor(heading: str) -> str:
    """The anchor GitHub gives a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = INLINE_CODE.sub(lambda match: match.group(0)[1:-1], heading).lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(page: Path) -> set[str]:
    return {heading_anchor(heading) for heading in HEADING.findall(FENCED_BLOCK.sub("", page.read_text()))}


def test_readme_is_short() -> None:
    size = len(README.read_bytes())
    assert size <= README_MAX_BYTES, f"README.md is {size} bytes, over {README_MAX_BYTES}: move detail to docs/"


def test_readme_links_every_doc() -> None:
    linked = {(REPO_ROOT / link.split("#")[0]).resolve() for link in relative_links(README)}
    unlinked = [page.name for page in sorted(DOCS.glob("*.md")) if page.resolve() not in linked]
    assert not unlinked, f"docs not linked from README.md: {unlinked}"


@pytest.mark.parametrize("page", markdown_pages(), ids=lambda page: str(page.relative_to(REPO_ROOT)))
def test_links_lead_to_existing_files_and_headings(page: Path) -> None:
    broken = []
    for link in relative_links(page):
        path_part, _, fragment = link.partition("#")
        target = (page.parent / path_part).resolve() if path_part else page
        if not target.exists():
            broken.append(f"{link} (no such file)")
        elif fragment and target.suffix == ".md" and fragment not in anchors(target):
            broken.append(f"{link} (no such heading)")
    assert not broken, f"{page.relative_to(REPO_ROOT)}: broken links: {broken}"
