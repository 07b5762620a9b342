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


def test_the_readme_s_first_figure_is_the_default_environment_s_and_its_sentence_reads_that_record():
    """The figure under the README's title is the reference (default) environment's cpu map, and the sentence under
    it quotes that record's numbers (the mean over its seeds), not those of the retired calibrated environment."""
    import json
    from collections import defaultdict

    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    first = re.search(r"!\[[^]]*\]\(([^)]+)\)", readme)[1]
    assert first == "docs/results/identifiability_map_cpu_reference.png"
    record = json.loads((ROOT / "docs/results/map_cpu_reference.json").read_text())
    assert record["map_config"]["environment"] == "reference"
    log_k = defaultdict(list)
    for run in record["runs"].values():
        log_k[run["train"]["variant"]].append(run["probes"]["ridge"]["contact"]["log_k"])
    sentence = readme[readme.index(first):readme.index("PokeWorld's default environment")]
    for variant in ("VX_t", "VX", "VFX"):
        assert f"{sum(log_k[variant]) / len(log_k[variant]):.2f} for {variant}" in sentence, variant
    assert "default reference environment" in sentence and "calibrated" not in sentence
