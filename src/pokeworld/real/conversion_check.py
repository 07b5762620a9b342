"""``check_synth_conversion``: compare a converted store of a synthetic RH20T-layout corpus with the corpus's ground
truth (:func:`pokeworld.real.synthetic.check_conversion`; docs/rh20t.md, "What conversion gives").

    python scripts/check_synth_conversion.py STORE ROOT [--out FILE.json]

STORE is the output of ``pokeworld rh20t-convert ROOT ...``, ROOT the output of ``pokeworld rh20t-synth``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..io import write_json
from .synthetic import check_conversion


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("store")
    ap.add_argument("root")
    ap.add_argument("--out", default="")
    a = ap.parse_args(argv)
    for p, what in ((a.store, "store"), (Path(a.root) / "truth" / "manifest.json", "truth manifest")):
        if not Path(p).exists():
            print(f"error: {what} {p} does not exist", file=sys.stderr)
            return 2
    res = check_conversion(a.store, a.root)
    print(json.dumps(res, indent=2))
    if a.out:
        write_json(a.out, res)
    return 0



__all__ = ["main"]
