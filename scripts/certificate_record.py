"""Add ``pokeworld certify`` records to a certificate record such as docs/results/certificates_cpu_reference.json.

    python scripts/certificate_record.py RECORD ENTRY PIECE.json [PIECE.json ...] [--section certificates]
                                         [--replace] [--provenance KEY TEXT]

ENTRY names the corpus (``standard``, ``bias1.5``, ...). The pieces, and the entry already in the record unless
``--replace``, are merged into one certification (:mod:`pokeworld.certificate_record`: same store, fit corpus and
settings, or one line saying which differs); machine paths become placeholders; ``--provenance`` records the
command behind the pieces under ``provenance[KEY]``. A record that does not exist yet is created with the budget and
environment of the first piece's store (``--preset``, ``--environment``).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from pokeworld.certificate_record import merge_records
from pokeworld.errors import DataError, PokeworldError
from pokeworld.io import read_json, read_json_if_present, write_json
from pokeworld.record_paths import without_machine_paths


def updated(record: dict, args: argparse.Namespace) -> dict:
    """``record`` with ``args.entry`` of ``args.section`` merged from the pieces (the record is not modified)."""
    section = dict(record.get(args.section) or {})
    pieces = [] if args.replace or args.entry not in section else [(f"{args.record}:{args.entry}",
                                                                   section[args.entry])]
    pieces += [(str(p), read_json(p, "a certificate record (written by `pokeworld certify`)")) for p in args.pieces]
    section[args.entry] = merge_records(pieces)
    out = {**record, args.section: section}
    if args.provenance:
        out["provenance"] = {**record.get("provenance", {}), args.provenance[0]: args.provenance[1]}
    return without_machine_paths(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("record", type=Path, help="the certificate record to add to (created if absent)")
    ap.add_argument("entry", help="the corpus the pieces certify (the entry's name in the record)")
    ap.add_argument("pieces", nargs="+", type=Path, help="certificates.json files written by `pokeworld certify`")
    ap.add_argument("--section", default="certificates",
                    help="the record's table to add to (certificates, or fit_on_probe_fit_split)")
    ap.add_argument("--replace", action="store_true", help="drop the entry already in the record")
    ap.add_argument("--provenance", nargs=2, metavar=("KEY", "TEXT"), help="the command behind the pieces")
    ap.add_argument("--preset", default="cpu", help="budget of a new record's store")
    ap.add_argument("--environment", default="reference", help="environment of a new record's store")
    args = ap.parse_args(argv)
    try:
        if os.path.islink(args.record):
            raise DataError(f"{args.record} is a link; give the record's own path")
        record = read_json_if_present(args.record, "a certificate record") or {
            "map_config": {"preset": args.preset, "environment": args.environment}}
        write_json(args.record, updated(record, args))
    except PokeworldError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    entry = read_json(args.record, "a certificate record")[args.section][args.entry]
    best = ", ".join(f"{kind} {t} {c['r2']:.2f} ({c['estimator']})" for kind, ts in entry["certificate"].items()
                     for t, c in ts.items())
    print(f"[certificate_record] {args.entry}: {best}")
    print(f"[certificate_record] wrote {args.record} ({args.section}.{args.entry}, {entry['pieces']} pieces)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
