"""What product text must not say: the project's development process instead of the method.

A reader has the repository, not its tracker: a bar is named by what it is ("half the paper's mean",
"within 2x of CMA-ES"), never by the issue, stop or session that set it, and nothing points to a document
outside the repository. :func:`forbidden_in` finds such words; tests/test_wording.py holds the tracked files
to it, tests/workflow/test_workflow.py a ``.test`` run's outputs.
"""
from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: Case-insensitive. Whitespace is required after "issue" so that base64 images in rendered notebooks
#: (letters and digits, no spaces) cannot match by chance.
FORBIDDEN = re.compile(
    r"\bissues?\s+#?\d+"                      # issue 12, Issue 20, issues 10, 18, issue #4
    r"|\bissue's\b|\bissue\s+(?:bar|criteri)"  # the bar, issue criterion
    r"|\bstops?\s+\d+\b"                      # stop 18
    r"|\bsessions?\s+\d+|\bthat session\b"     # session 3, that session
    r"|\bmethod[- ]notes\b|\bnotes, section\b|\bshared/(?:paper|design)\b",  # documents outside the repository
    re.IGNORECASE)

#: Case-insensitive. How a page came to be, which belongs to git or to the measurement logs under docs/results/, not
#: to a page that states the method: a commit as the place of a result, earlier versions, what is "now" or "then".
HISTORY = re.compile(
    r"\bat commit [0-9a-f]{7,40}\b"           # at commit d6a70b4
    r"|\ba first version\b|\bnow the default\b"
    r"|\b(?:was|were) then\b",               # as the passes were then
    re.IGNORECASE)

#: Third-party texts kept verbatim (a licence may speak of "issue tracking systems").
VERBATIM = re.compile(r"(^|/)LICEN[CS]E[^/]*$")

#: The files that hold these patterns on purpose: this module and its tests.
SELF = {"tests/wording.py", "tests/test_wording.py"}


def forbidden_in(text: str) -> list[tuple[int, str]]:
    """``(line number, matched words)`` for each forbidden phrase of ``text``."""
    return [(text.count("\n", 0, match.start()) + 1, match.group(0)) for match in FORBIDDEN.finditer(text)]


def history_in(text: str) -> list[tuple[int, str]]:
    """``(line number, matched words)`` for each phrase of ``text`` that tells its history (:data:`HISTORY`)."""
    return [(text.count("\n", 0, match.start()) + 1, match.group(0)) for match in HISTORY.finditer(text)]


def readable_text(path: Path) -> str | None:
    """``path``'s text, or None for a binary file (a NUL byte, or not UTF-8)."""
    data = path.read_bytes()
    if b"\0" in data:
        return None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return None


def offences(paths: list[Path], root: Path, find=forbidden_in) -> list[str]:
    """``file:line: words`` for each phrase ``find`` reports in the text files among ``paths``."""
    found = []
    for path in paths:
        text = readable_text(path)
        if text is None:
            continue
        found += [f"{path.relative_to(root).as_posix()}:{line}: {words!r}" for line, words in find(text)]
    return found


def tracked_files(root: Path = ROOT) -> list[str]:
    """The repository's tracked files (``git ls-files``), as paths relative to ``root``."""
    listed = subprocess.run(["git", "ls-files", "-z"], cwd=root, capture_output=True, check=True).stdout
    return [name for name in listed.decode().split("\0") if name]
