"""The paper's rejected drift constructions (App. C "Constructing the cells" (i), (ii)): the summary the ledger reads
on planted certificates, and the record script end to end at the tiny preset."""

import importlib.util
from pathlib import Path

import pytest

from pokeworld.io import read_json
from pokeworld.rejected_cells import FAILS_BELOW, certify_construction, drift_r2, markdown, summary

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "drift_certificates.py"


def _certs(linear_all, glide=0.9):
    est = {"linear": {"all": {"drift_x": linear_all, "drift_y": linear_all + 0.02},
                      "contact": {"drift_x": 0.0, "drift_y": 0.01},
                      "glide": {"drift_x": glide, "drift_y": glide}}}
    return {"estimators": est, "counts": {"all": {"test": 100}, "contact": {"test": 60}, "glide": {"test": 20}}}


def test_a_drift_certificate_is_the_mean_of_its_two_components_and_fails_below_the_threshold():
    s = summary({"drift": _certs(0.01), "drift_fixed_gamma": _certs(0.5)})
    assert s["drift"]["linear_all"] == pytest.approx(0.02) and s["drift"]["linear_fails"] is True
    assert s["drift_fixed_gamma"]["linear_fails"] is False  # a readable drift passes: the rule can come out either way
    assert s["drift"]["gru_all"] is None and s["drift"]["test_windows"] == {"all": 100, "contact": 60, "glide": 20}
    assert drift_r2({"estimators": {"linear": {"all": {"drift_x": 0.3}}}}, "linear", "all") is None  # one component
    assert FAILS_BELOW == 0.1
    text = markdown({"map_config": {"preset": "cpu"}, "estimators": ["linear"], "summary": s})
    assert "| (i) drift, drag per episode | linear | +0.02 | +0.01 | +0.90 |" in text and "| gru |" not in text
    assert "fails (+0.02)" in text and "passes (+0.51)" in text


def test_an_unknown_construction_is_refused_before_anything_is_generated(tmp_path):
    with pytest.raises(ValueError, match="unknown construction"):
        certify_construction("bias0.5", "tiny", tmp_path, ("linear",))
    with pytest.raises(ValueError, match="recurrent kinds"):
        certify_construction("drift", "tiny", tmp_path, ("gru",), ("moving",))
    assert not any(tmp_path.iterdir())


@pytest.mark.slow
def test_the_script_writes_a_record_the_ledger_can_read(tmp_path):
    spec = importlib.util.spec_from_file_location("drift_certificates", SCRIPT)
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    out = tmp_path / "drift.json"
    args = ["--preset", "tiny", "--data", str(tmp_path / "data"), "--estimators", "linear", "gru",
            "--recurrent-kinds", "all", "--out", str(out)]
    assert script.main(args) == 0
    assert script.main(args) == 0  # a second run finds every corpus and certificate current (and its stores intact)
    record = read_json(out, "the drift record")
    assert record["map_config"] == {"preset": "tiny", "environment": "reference"}
    assert set(record["summary"]) == {"drift", "drift_fixed_gamma"}
    assert isinstance(record["summary"]["drift"]["linear_fails"], bool)
    assert record["summary"]["drift"]["gru_all"] is not None and record["summary"]["drift"]["gru_contact"] is None
    assert out.with_suffix(".md").read_text().startswith("# The rejected drift constructions")
