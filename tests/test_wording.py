"""Text a researcher can read. Product text speaks of the method alone (tests/wording.py): no issue, stop or
session numbers and no document outside the repository, in any tracked file. Every link of the README and the
docs resolves; the docs keep short lines and table cells; the README stays short."""
from __future__ import annotations

import re

import pytest

from wording import ROOT, SELF, VERBATIM, forbidden_in, history_in, offences, tracked_files


def test_no_tracked_file_speaks_of_issues_stops_or_outside_documents():
    names = [name for name in tracked_files() if name not in SELF and not VERBATIM.search(name)]
    paths = [ROOT / name for name in names if (ROOT / name).is_file()]
    assert len(paths) > 100  # the listing worked
    assert offences(paths, ROOT) == []


@pytest.mark.parametrize("planted, found", [
    ("see issue 12", "issue 12"), ("Issue 20's bar", "Issue 20"), ("ISSUES 10, 18", "ISSUES 10"), ("issue #4", "issue #4"),
    ("the issue's bar", "issue's"), ("stop 18", "stop 18"), ("that session", "that session"),
    ("the method notes", "method notes"), ("method-notes.md", "method-notes")])
def test_a_planted_word_is_found(tmp_path, planted, found):
    """The negative control: each phrase, planted in a file, is reported with its line and words."""
    path = tmp_path / "notes.md"
    path.write_text(f"A clean line.\nA line that says {planted} in passing.\n")
    assert offences([path], tmp_path) == [f"notes.md:2: {found!r}"]


@pytest.mark.parametrize("clean", ["half the paper's mean", "within 2x of CMA-ES", "a session fixture",
                                   "it stops at zoom 0", "tissue 12",
                                   "iVBORw0KGgoissue5AAAA"])
def test_ordinary_words_pass(clean):
    assert forbidden_in(clean) == []


def documentation_pages() -> list:
    """The README and every page under docs/ but the measurement logs and snapshots of docs/results/."""
    results = ROOT / "docs" / "results"
    return [ROOT / "README.md", *(page for page in sorted((ROOT / "docs").rglob("*.md")) if results not in page.parents)]


def test_the_pages_state_the_method_not_its_history():
    pages = documentation_pages()
    assert len(pages) >= 12
    assert offences(pages, ROOT, history_in) == []


@pytest.mark.parametrize("planted, found", [
    ("measured at commit 0123abc on runs 60-119", "at commit 0123abc"), ("A first version ran", "A first version"),
    ("depth_zoom=1, now the default", "now the default"), ("as the passes were then", "were then")])
def test_a_planted_history_phrase_is_found(tmp_path, planted, found):
    """The negative control: a history phrase planted in a method page is reported with its line and words."""
    path = tmp_path / "method" / "floor.md"
    path.parent.mkdir()
    path.write_text(f"# The floor\n{planted}.\n")
    assert offences([path], tmp_path, history_in) == [f"method/floor.md:2: {found!r}"]


@pytest.mark.parametrize("clean", ["the commit and date of each figure", "the first version of the paper's rule",
                                   "then the kernel narrows", "the default is 2"])
def test_method_words_pass_the_history_check(clean):
    assert history_in(clean) == []


#: A Markdown link or image: [text](target) or ![alt](target).
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


def _anchor(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation but hyphens and underscores dropped, spaces hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def _anchors(path) -> set[str]:
    text = re.sub(r"^```.*?^```", "", path.read_text(), flags=re.M | re.S)
    return {_anchor(match) for match in re.findall(r"^#{1,6}\s+(.*?)\s*#*$", text, flags=re.M)}


def broken_links(markdown) -> list[str]:
    """The links of ``markdown`` (a file) whose file, or heading anchor, does not exist."""
    broken = []
    for target in LINK.findall(markdown.read_text()):
        if re.match(r"[a-z]+:", target):  # https:, mailto:: outside the repository
            continue
        file, _, anchor = target.partition("#")
        resolved = (markdown.parent / file).resolve() if file else markdown
        if not resolved.exists():
            broken.append(target)
        elif anchor and resolved.suffix == ".md" and anchor not in _anchors(resolved):
            broken.append(target)
    return broken


def test_every_link_of_the_readme_and_docs_resolves():
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    assert len(LINK.findall(pages[0].read_text())) >= 10
    assert {page.name: broken_links(page) for page in pages if broken_links(page)} == {}


def test_a_broken_link_is_found(tmp_path):
    (tmp_path / "there.md").write_text("# A heading, with words\n")
    page = tmp_path / "page.md"
    page.write_text("[ok](there.md) [ok](there.md#a-heading-with-words) [web](https://example.org)\n"
                    "[gone](missing.md) ![gone](fig.png) [bad anchor](there.md#nowhere)\n")
    assert broken_links(page) == ["missing.md", "fig.png", "there.md#nowhere"]


def long_lines(markdown: str) -> list[str]:
    """Table cells over 60 words and prose lines over 120 characters (code blocks aside)."""
    found, in_code = [], False
    for number, line in enumerate(markdown.splitlines(), start=1):
        if line.startswith("```"):
            in_code = not in_code
        elif in_code:
            continue
        elif line.startswith("|"):
            found += [f"{number}: a cell of {len(cell.split())} words"
                      for cell in re.split(r"(?<!\\)\|", line)[1:-1] if len(cell.split()) > 60]
        elif len(line) > 120:
            found.append(f"{number}: a line of {len(line)} characters")
    return found


def test_docs_read_in_short_lines_and_cells():
    pages = [*sorted((ROOT / "docs").glob("*.md")), *sorted((ROOT / "docs" / "method").glob("*.md"))]
    assert len(pages) >= 10
    assert {page.name: long_lines(page.read_text()) for page in pages if long_lines(page.read_text())} == {}
    assert long_lines("| " + "word " * 61 + "|\n" + "x" * 121 + "\n```\n" + "y" * 200 + "\n```\n") == [
        "1: a cell of 61 words", "2: a line of 121 characters"]


def test_the_readme_is_short():
    assert len((ROOT / "README.md").read_text().splitlines()) <= 150
