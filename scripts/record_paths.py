"""Records name no machine's paths (pokeworld.record_paths): every absolute path in the records under docs/results/
(JSON and their Markdown reports, in every folder) as a placeholder.

    python scripts/record_paths.py [--check] [RECORD.json|REPORT.md ...]     (default: every record under docs/results)

``--check`` lists the records that still hold a path and exits 1 if any does. A device's raw log (``*.log``) is kept
byte for byte as it came back: it is the evidence a lease's record is read from, not a record.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from pokeworld.record_paths import PATH, placeholder, without_machine_paths

ROOT = Path(__file__).resolve().parents[1]


def cleaned(path: Path) -> tuple[str, str]:
    """(the file's text, the same text with every machine path a placeholder); JSON is rewritten through its parsed
    values (numbers untouched), Markdown line by line."""
    text = path.read_text()
    if path.suffix == ".json":
        data = json.loads(text)
        clean = without_machine_paths(data)
        if clean == data:
            return text, text
        return text, json.dumps(clean, indent=2, sort_keys=True) + "\n"  # as pokeworld.io writes records
    return text, PATH.sub(lambda m: placeholder(m.group(0)), text)


def default_records() -> list[Path]:
    base = ROOT / "docs" / "results"
    return sorted(p for p in base.rglob("*") if p.is_file() and p.suffix in (".json", ".md"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("records", nargs="*", type=Path)
    ap.add_argument("--check", action="store_true")
    a = ap.parse_args()
    records = a.records or default_records()
    holding = []
    for path in records:
        text, clean = cleaned(path)
        if clean != text:
            holding.append(path)
            if not a.check:
                path.write_text(clean)
    verb = "hold" if a.check else "had"
    print(f"[record_paths] {len(holding)} of {len(records)} records {verb} a machine's paths"
          + (f": {', '.join(str(p.relative_to(ROOT)) if p.is_relative_to(ROOT) else str(p) for p in holding)}"
             if a.check and holding else "")
          + ("" if a.check else f"; rewritten with placeholders: {', '.join(p.name for p in holding) or 'none'}"))
    return 1 if a.check and holding else 0


if __name__ == "__main__":
    sys.exit(main())
