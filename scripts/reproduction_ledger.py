"""Write the reproduction ledger from the committed records (no training, no measurement; seconds):

    python scripts/reproduction_ledger.py

reads every record under docs/results that :mod:`pokeworld.reproduction` names and writes
docs/results/reproduction.json (every row: the paper's values, the released ones, ours with the record and JSON path
each was read from, and the computed verdict) and docs/results/reproduction.md (the summary line and one table per
part of the paper). Run it again whenever a record changes; tests/test_reproduction.py fails while the committed
ledger and the records disagree. ``--records DIR`` and ``--out STEM`` point it elsewhere (a planted folder).
"""

import argparse
from pathlib import Path

from pokeworld.io import save_text, write_json
from pokeworld.reproduction import VERDICTS, ledger, ledger_markdown

RESULTS = Path(__file__).resolve().parents[1] / "docs" / "results"


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--records", type=Path, default=RESULTS, help="folder of the records (default: docs/results)")
    ap.add_argument("--out", type=Path, default=RESULTS / "reproduction",
                    help="output stem: STEM.json and STEM.md (default: docs/results/reproduction)")
    args = ap.parse_args(argv)
    result = ledger(args.records)
    write_json(args.out.with_suffix(".json"), result)
    save_text(args.out.with_suffix(".md"), ledger_markdown(result))
    print(" · ".join(f"{result['counts'][v]} {v}" for v in VERDICTS) + f" ({len(result['rows'])} rows)")
    return result


if __name__ == "__main__":
    main()
