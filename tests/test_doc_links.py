"""Every relative link in README.md, benchmarks/README.md and docs/ names a file that exists: records move (archive/), and a link written
from one folder breaks when its page moves to another."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)\s]*)?\)")


def relative_links(text: str) -> list[str]:
    """The targets of a page's relative links (anchors dropped; URLs with a scheme left out)."""
    return [m[1] for m in LINK.finditer(text) if not re.match(r"[a-z]+:", m[1])]


def test_the_link_pattern_finds_relative_links_and_leaves_urls():
    page = "[a](docs/x.md) [b](https://example.org/y) [c](../z.json#part) [d](mailto:someone)"
    assert relative_links(page) == ["docs/x.md", "../z.json"]


def test_every_relative_link_in_the_docs_resolves():
    pages = [ROOT / "README.md", ROOT / "benchmarks" / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    broken = [f"{page.relative_to(ROOT)} -> {target}" for page in pages
              for target in relative_links(page.read_text(encoding="utf-8")) if not (page.parent / target).exists()]
    assert not broken, "broken links: " + "; ".join(broken)
