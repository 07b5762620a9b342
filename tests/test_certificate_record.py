"""Pieces of one certification merged into one record (pokeworld.certificate_record and its script): the best
estimator and the gate recomputed across pieces, and every kind of mismatch refused with one line."""

import importlib.util
import json
from pathlib import Path

import pytest

from pokeworld.certificate_record import merge_records
from pokeworld.errors import DataError

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "certificate_record.py"
SETTINGS = {"window": 16, "stride": 4, "max_windows": 30000, "fit_episodes": 1920, "seed": 0, "gru_hidden": 96,
            "gru_layers": 2, "epochs": 150, "patience": 12, "separate_targets": True, "pixel_size": 0}


def piece(estimators: dict, targets=("log_m", "gamma", "log_k"), sha="abc", **settings) -> dict:
    """A certify record as ``pokeworld certify`` writes one (only the parts a merge reads)."""
    names = list(estimators)
    return {"estimators": estimators, "counts": {"contact": {"fit": 100, "test": 40}},
            "config": {**SETTINGS, **settings, "estimators": names, "targets": list(targets), "kinds": ["contact"],
                       "data": "/home/someone/out/data/standard", "out": "/tmp/x.json"},
            "dataset": {"content_sha256": sha, "corpus": "standard", "path": "/home/someone/out/data/standard"},
            "fit_corpus": {"source": "certificate corpus", "episodes": 1920, "content_sha256": "fit"},
            "certificate": {}, "gate": {}, "warnings": []}


LINEAR = {"linear": {"contact": {"log_m": 0.05, "gamma": 0.0, "log_k": 0.2}}}
GRU = {"gru": {"contact": {"log_m": 0.8, "gamma": 0.3, "log_k": 0.9}}}


def test_two_pieces_give_the_record_one_call_with_both_estimators_would_have_written():
    merged = merge_records([("a", piece(LINEAR)), ("b", piece(GRU))])
    assert merged["estimators"] == {**LINEAR, **GRU}
    assert merged["certificate"]["contact"]["log_k"] == {"r2": 0.9, "estimator": "gru"}
    # the gate reads the GRU oracle once it is among the pieces: γ 0.3 fails the 0.4 rule, mass and stiffness pass
    assert merged["gate"]["gamma"]["passed"] is False and merged["gate"]["gamma"]["oracle"] == 0.3
    assert merged["gate"]["log_m"]["paper_rule_passed"] is True
    assert merged["config"]["estimators"] == ["linear", "gru"] and "out" not in merged["config"]
    assert merged["pieces"] == 2
    alone = merge_records([("a", piece(LINEAR))])  # without the GRU the gate has no oracle
    assert alone["gate"]["log_k"]["oracle"] is None and alone["certificate"]["contact"]["log_k"]["estimator"] == "linear"
    again = merge_records([("merged", merged), ("a", piece(LINEAR))])  # a cell fit twice that agrees is kept once
    assert again["estimators"] == merged["estimators"] and again["pieces"] == 3


def test_drag_coverage_travels_with_its_piece_and_a_disagreeing_copy_is_refused():
    cov = {"drag": {"contact": {"windows": 40, "with_glide_pair": 0.75, "r2_with_glide_pair": 1.0, "r2_without": -0.1,
                                "r2_lost_without": 0.2}}}
    drag = {"drag": {"contact": {"gamma": 0.8}}}
    merged = merge_records([("a", piece(LINEAR)), ("b", {**piece(drag), "drag_coverage": cov})])
    assert merged["drag_coverage"] == cov
    assert "drag_coverage" not in merge_records([("a", piece(LINEAR)), ("b", piece(GRU))])
    other = {"drag": {"contact": {**cov["drag"]["contact"], "with_glide_pair": 0.5}}}
    with pytest.raises(DataError, match="coverage"):
        merge_records([("a", {**piece(drag), "drag_coverage": cov}), ("b", {**piece(drag), "drag_coverage": other})])


def test_targets_certified_separately_join_under_one_estimator():
    m = merge_records([("k", piece({"gru": {"contact": {"log_k": 0.9}}}, targets=("log_k",))),
                       ("m", piece({"gru": {"contact": {"log_m": 0.8}}}, targets=("log_m",)))])
    assert m["estimators"]["gru"]["contact"] == {"log_k": 0.9, "log_m": 0.8} and m["config"]["targets"] == ["log_k", "log_m"]


@pytest.mark.parametrize("other, words", [
    (piece(GRU, sha="def"), "content hash"),
    (piece(GRU, window=8), "setting window"),
    (piece(GRU, fit_episodes=0), "setting fit_episodes"),
    (piece({"linear": {"contact": {"log_m": 0.5}}}), "fit twice disagrees"),
    ({"estimators": {}}, "not a record written by `pokeworld certify`"),
    ([1, 2], "not a certificate record"),
])
def test_pieces_of_different_certifications_are_refused_with_what_differs(other, words):
    with pytest.raises(DataError, match=words):
        merge_records([("a", piece(LINEAR)), ("b", other)])


def test_differing_window_counts_are_refused():
    other = piece(GRU)
    other["counts"]["contact"]["test"] = 41
    with pytest.raises(DataError, match="different windows"):
        merge_records([("a", piece(LINEAR)), ("b", other)])


def _script():
    spec = importlib.util.spec_from_file_location("certificate_record_script", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_script_grows_an_entry_without_machine_paths_and_refuses_a_link(tmp_path, capsys):
    main = _script().main
    a, b, record = tmp_path / "a.json", tmp_path / "b.json", tmp_path / "record.json"
    a.write_text(json.dumps(piece(LINEAR)))
    b.write_text(json.dumps(piece(GRU)))
    assert main([str(record), "standard", str(a), "--provenance", "linear", "pokeworld certify DIR"]) == 0
    assert main([str(record), "standard", str(b)]) == 0  # the entry already there is the first piece
    out = json.loads(record.read_text())
    entry = out["certificates"]["standard"]
    assert set(entry["estimators"]) == {"linear", "gru"} and entry["pieces"] == 2
    assert out["map_config"] == {"preset": "cpu", "environment": "reference"}
    assert out["provenance"] == {"linear": "pokeworld certify DIR"}
    assert "/home/someone" not in record.read_text() and "<machine>/" in record.read_text()
    assert "wrote" in capsys.readouterr().out
    assert main([str(record), "standard", str(a), "--replace"]) == 0
    assert set(json.loads(record.read_text())["certificates"]["standard"]["estimators"]) == {"linear"}
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(piece(GRU, sha="zzz")))
    assert main([str(record), "standard", str(bad)]) == 2
    assert "content hash" in capsys.readouterr().err
    link = tmp_path / "link.json"
    link.symlink_to(record)
    assert main([str(link), "standard", str(b)]) == 2 and "is a link" in capsys.readouterr().err
