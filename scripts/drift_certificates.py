"""Certify the paper's rejected drift constructions (App. C "Constructing the cells" (i), (ii)) and write their record.

Generates the two drift corpora of the reference environment (``drift``: drag per episode; ``drift_fixed_gamma``:
drag fixed at 1.5), certifies their drift acceleration with the linear and GRU estimators on all, contact and glide
windows (:mod:`pokeworld.rejected_cells`), and writes the record beside the paper's statements:

    python scripts/drift_certificates.py --preset cpu --data out/drift --out docs/results/drift_certificates_cpu.json

Re-running skips every corpus and certificate that is already current. ``--estimators linear`` alone takes about two
minutes at ``cpu``; each GRU fit (one per component and window kind) about 7 minutes on one thread, so
``--recurrent-kinds all`` fits the GRU on every window only (four fits for the two constructions).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from pokeworld import __version__
from pokeworld.errors import PokeworldError
from pokeworld.evaluate.tables import git_commit
from pokeworld.io import check_outputs, save_text, write_json
from pokeworld.rejected_cells import CONSTRUCTIONS, KINDS, certify_construction, markdown, summary


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", default="cpu", choices=("tiny", "cpu", "paper"), help="generate and certify preset")
    ap.add_argument("--data", default="out/drift", help="folder of the two drift corpora (created)")
    ap.add_argument("--estimators", nargs="+", default=["linear", "gru"], help="certificate estimators")
    ap.add_argument("--recurrent-kinds", nargs="+", default=list(KINDS), choices=list(KINDS),
                    help="window kinds the GRU is fit on (every kind by default; each fit takes minutes)")
    ap.add_argument("--constructions", nargs="+", default=list(CONSTRUCTIONS), choices=list(CONSTRUCTIONS))
    ap.add_argument("--out", default="docs/results/drift_certificates_cpu.json",
                    help="the record (a .md of the same name is written beside it)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    try:
        check_outputs(out.parent, out.name, out.with_suffix(".md").name)
        t0 = time.time()
        certs = {}
        for i, corpus in enumerate(args.constructions, 1):
            print(f"[drift] {i}/{len(args.constructions)}: {CONSTRUCTIONS[corpus]}", flush=True)
            certs[corpus] = certify_construction(corpus, args.preset, Path(args.data), tuple(args.estimators),
                                                 tuple(args.recurrent_kinds))
        # map_config: the budget and environment, where the reproduction ledger reads them in every record
        record = {"map_config": {"preset": args.preset, "environment": "reference"}, "estimators": args.estimators,
                  "recurrent_kinds": args.recurrent_kinds,
                  "kinds": list(KINDS), "version": __version__, "commit": git_commit(),
                  "command": "python scripts/drift_certificates.py " + " ".join(argv if argv is not None
                                                                                else sys.argv[1:]),
                  "seconds": round(time.time() - t0, 1), "summary": summary(certs),
                  "certificates": {c: {k: v for k, v in r.items() if k in ("estimators", "counts", "dataset")}
                                   for c, r in certs.items()}}
        write_json(out, record)
        save_text(out.with_suffix(".md"), markdown(record))
    except PokeworldError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"[drift] wrote {out} and {out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
