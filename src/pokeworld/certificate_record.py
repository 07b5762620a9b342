"""One corpus's certificates from several ``pokeworld certify`` records.

A corpus is often certified in pieces: the map's estimators first, a slow estimator (the pixel GRU, the GRU with
contact geometry) later, one target at a time. Each piece is a complete ``certify`` record. :func:`merge_records`
joins pieces of the *same* certification — same store (content hash), same fit corpus, same windows and estimator
settings — into the record a single ``certify`` call with every estimator would have written: the estimators'
scores side by side, the best-estimator table and the gate recomputed from them. Pieces that differ in any of these
are refused with the field that differs, since their scores are not comparable cell by cell; a cell fit twice must
agree (a rerun with the same settings reproduces it), else the merge is refused rather than one of the two dropped.
"""

from __future__ import annotations

from .certify import certificate_table, gate
from .errors import DataError

# settings that change what an estimator's score means; two pieces must agree on each
SHARED_SETTINGS = ("window", "stride", "max_windows", "fit_episodes", "seed", "gru_hidden", "gru_layers", "epochs",
                   "patience", "separate_targets", "pixel_size")
RECORD_KEYS = ("estimators", "counts", "config", "dataset", "fit_corpus")
SAME_SCORE = 1e-9  # a cell fit twice with the same settings and seed reproduces to float precision


def check_piece(piece: object, name: str) -> dict:
    """``piece`` if it has the parts of a ``certify`` record, else one DataError naming what is missing."""
    if not isinstance(piece, dict):
        raise DataError(f"{name} is not a certificate record (a JSON object written by `pokeworld certify`)")
    missing = [k for k in RECORD_KEYS if not isinstance(piece.get(k), dict)]
    if missing:
        raise DataError(f"{name} lacks {', '.join(missing)}: not a record written by `pokeworld certify`")
    return piece


def _agree(pieces: list[tuple[str, dict]], what: str, get) -> None:
    first_name, first = pieces[0]
    for name, p in pieces[1:]:
        if get(p) != get(first):
            raise DataError(f"{name} and {first_name} differ in {what} ({get(p)!r} vs {get(first)!r}): "
                            "they are not pieces of one certification; keep them as separate entries")


def _union_estimators(pieces: list[tuple[str, dict]]) -> dict:
    out: dict = {}
    for name, p in pieces:
        for est, kinds in p["estimators"].items():
            for kind, scores in kinds.items():
                cell = out.setdefault(est, {}).setdefault(kind, {})
                for target, r2 in scores.items():
                    if target in cell and abs(cell[target] - r2) > SAME_SCORE:
                        raise DataError(f"{name} scores {est} on {kind} windows for {target} {r2:.4f}, another "
                                        f"piece {cell[target]:.4f}: the same cell fit twice disagrees; keep one")
                    cell[target] = r2
    return out


def _union_drag_coverage(pieces: list[tuple[str, dict]]) -> dict:
    """The drag estimators' coverage (``certify.drag_coverage``) of every piece that has it; a cell in two pieces
    must agree, as its R² does."""
    out: dict = {}
    for name, p in pieces:
        for est, kinds in (p.get("drag_coverage") or {}).items():
            for kind, cov in kinds.items():
                have = out.setdefault(est, {}).get(kind)
                if have is not None and have != cov:
                    raise DataError(f"{name} and another piece differ in {est}'s coverage of {kind} windows: the same "
                                    "cell fit twice disagrees; keep one")
                out[est][kind] = cov
    return out


def _union_counts(pieces: list[tuple[str, dict]]) -> dict:
    out: dict = {}
    for name, p in pieces:
        for kind, c in p["counts"].items():
            if kind in out and out[kind] != c:
                raise DataError(f"{name} counts {kind} windows {c}, another piece {out[kind]}: different windows")
            out[kind] = c
    return out


def _ordered_union(lists) -> list:
    out: list = []
    for xs in lists:
        out += [x for x in xs if x not in out]
    return out


def merge_records(pieces: list[tuple[str, dict]]) -> dict:
    """The record of one certification from its pieces ``(name, record)`` (names are for messages only)."""
    if not pieces:
        raise DataError("no certificate records to merge")
    pieces = [(name, check_piece(p, name)) for name, p in pieces]
    _agree(pieces, "the store (dataset content hash)", lambda p: p["dataset"].get("content_sha256"))
    _agree(pieces, "the fit corpus", lambda p: p["fit_corpus"])
    for key in SHARED_SETTINGS:
        _agree(pieces, f"the setting {key}", lambda p, k=key: p["config"].get(k))
    estimators = _union_estimators(pieces)
    targets = _ordered_union(p["config"].get("targets", []) for _, p in pieces)
    certificate = certificate_table(estimators, targets)
    config = {k: v for k, v in pieces[0][1]["config"].items() if k != "out"}
    config.update(estimators=_ordered_union(p["config"].get("estimators", []) for _, p in pieces),
                  kinds=_ordered_union(p["config"].get("kinds", []) for _, p in pieces), targets=targets)
    return {"estimators": estimators, "counts": _union_counts(pieces), "certificate": certificate,
            "gate": gate(certificate, estimators), "config": config, "dataset": pieces[0][1]["dataset"],
            "fit_corpus": pieces[0][1]["fit_corpus"],
            "warnings": _ordered_union(p.get("warnings", []) for _, p in pieces),
            "pieces": sum(int(p.get("pieces", 1)) for _, p in pieces),
            **({"drag_coverage": cov} if (cov := _union_drag_coverage(pieces)) else {})}


__all__ = ["SHARED_SETTINGS", "check_piece", "merge_records"]
