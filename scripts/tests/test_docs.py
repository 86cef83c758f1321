"""The documentation as a reader meets it: README.md is a short front door that links every page of
docs/, every relative link and anchor in README.md and docs/*.md leads somewhere, and the pages for
users tell no development history (no issue numbers, no commit hashes: those belong to the
benchmark pages, which keep the commit behind each figure)."""
from __future__ import annotations

import re
import unicodedata
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]
DOCS = REPO_ROOT / "docs"
README_MAX_LINES = 300
# Pages written for users; BENCHMARKS.md, RELIABILITY.md, ARCHITECTURE.md and the result folders may
# name commits, since their figures are tied to them.
USER_PAGES = ["README.md", "docs/USER_GUIDE.md", "docs/HEADLESS.md", "docs/LIBRARY.md", "docs/API.md",
              "docs/CAMERAS.md", "docs/BLENDER_VERSIONS.md"]

LINK = re.compile(r"(?<!!)\[[^\]]*\]\(([^)\s]+)\)|!\[[^\]]*\]\(([^)\s]+)\)")


def _pages() -> list[Path]:
    return [REPO_ROOT / "README.md", *sorted(DOCS.glob("*.md"))]


def _prose(text: str) -> str:
    """The text outside fenced code blocks (code may hold anything, links are not followed there)."""
    return re.sub(r"^```.*?^```", "", text, flags=re.M | re.S)


def _anchors(text: str) -> set[str]:
    """GitHub's heading anchors: lower case, punctuation dropped, spaces to hyphens."""
    out = set()
    for title in re.findall(r"^#{1,6}\s+(.+?)\s*$", _prose(text), flags=re.M):
        slug = "".join(c for c in unicodedata.normalize("NFKD", title.lower())
                       if c.isalnum() or c in " -_").replace(" ", "-")
        out.add(slug)
    return out


def test_readme_is_a_short_front_door():
    lines = (REPO_ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines; move detail into docs/"
    text = "\n".join(lines)
    for command in ("bash scripts/demo.sh", "bash scripts/test.sh"):
        assert command in text, f"README.md must give the command {command!r}"


def test_readme_links_every_docs_page():
    text = (REPO_ROOT / "README.md").read_text(encoding="utf-8")
    linked = {m.group(1) or m.group(2) for m in LINK.finditer(text)}
    linked = {link.split("#")[0] for link in linked}
    missing = [f"docs/{p.name}" for p in sorted(DOCS.glob("*.md")) if f"docs/{p.name}" not in linked]
    assert not missing, f"README.md does not link {missing}"


def test_every_relative_link_and_anchor_resolves():
    broken = []
    for page in _pages():
        text = page.read_text(encoding="utf-8")
        for m in LINK.finditer(_prose(text)):
            target = m.group(1) or m.group(2)
            if re.match(r"^[a-z]+://|^mailto:", target):
                continue
            path, _, anchor = target.partition("#")
            dest = (page.parent / path).resolve() if path else page
            if not dest.exists():
                broken.append(f"{page.relative_to(REPO_ROOT)}: {target} (no such file)")
            elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest.read_text(encoding="utf-8")):
                broken.append(f"{page.relative_to(REPO_ROOT)}: {target} (no heading with that anchor)")
    assert not broken, "\n".join(broken)


def test_user_pages_tell_no_development_history():
    found = []
    for rel in USER_PAGES:
        page = REPO_ROOT / rel
        if not page.exists():
            continue
        for n, line in enumerate(_prose(page.read_text(encoding="utf-8")).splitlines(), 1):
            if re.search(r"\b[Ii]ssue[s]?\s*#?\d+|\bcommit\s+[0-9a-f]{7,40}\b|\bbefore this work\b", line):
                found.append(f"{rel}:{n}: {line.strip()[:100]}")
    assert not found, "user pages name issues or commits:\n" + "\n".join(found)


def test_link_checker_finds_a_broken_anchor(tmp_path):
    """The checks above can fail: a heading's anchor is computed as GitHub does."""
    assert _anchors("## Several processes or GPUs: `torchrun`\n") == {"several-processes-or-gpus-torchrun"}
    assert "no-such" not in _anchors("## Something else\n")
