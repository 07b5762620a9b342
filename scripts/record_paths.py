"""Records name no machine's paths (pokeworld.record_paths): every absolute path in the JSON records under
docs/results/ as a placeholder.

    python scripts/record_paths.py [--check] [RECORD.json ...]     (default: every docs/results/*.json)

``--check`` lists the records that still hold a path and exits 1 if any does.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from pokeworld.record_paths import without_machine_paths

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("records", nargs="*", type=Path)
    ap.add_argument("--check", action="store_true")
    a = ap.parse_args()
    records = a.records or sorted((ROOT / "docs" / "results").glob("*.json"))
    holding = []
    for path in records:
        data = json.loads(path.read_text())
        clean = without_machine_paths(data)
        if clean != data:
            holding.append(path)
            if not a.check:
                path.write_text(json.dumps(clean, indent=2, sort_keys=True) + "\n")  # as pokeworld.io writes records
    verb = "hold" if a.check else "had"
    print(f"[record_paths] {len(holding)} of {len(records)} records {verb} a machine's paths"
          + ("" if a.check else f"; rewritten with placeholders: {', '.join(p.name for p in holding) or 'none'}"))
    return 1 if a.check and holding else 0


if __name__ == "__main__":
    sys.exit(main())
