"""The factorial at λ 0.1 (paper App. C: Table "targets"' ordering is unchanged): the ordering rule, the runs it
shares with the λ sweep, its report section and its ledger row on planted records."""

import pytest

from pokeworld.experiments import all_specs, lambda_factorial
from pokeworld.experiments import make_config as map_config
from pokeworld.experiments.factorial import FACTORIAL
from pokeworld.experiments.lambda_factorial import ordering_holds
from pokeworld.io import write_json
from pokeworld.reproduction import NOT_REPRODUCED, NOT_RUN, REPRODUCED_AT_CPU, ROWS, ledger

TABLE = {v: p["log_k"] for v, p in FACTORIAL.items()}  # Table "targets", log k (means of the two seeds)
SIX = tuple(TABLE)


def test_the_papers_table_keeps_its_own_ordering_and_a_swap_or_a_closed_gap_breaks_it():
    assert ordering_holds(TABLE) is True
    assert ordering_holds({**TABLE, "VFX": TABLE["VX"] - 0.05}) is True  # a reversal inside the tolerance is not called
    assert ordering_holds({**TABLE, "VX_t": 0.0, "VF": 0.40}) is False  # touch moved to the wrong variant
    assert ordering_holds({**TABLE, "VX_t": 0.05}) is False  # a touch reader no longer above the others
    assert ordering_holds({**TABLE, "VFX": 0.20}) is False  # VFX reversed against VX by 0.26
    assert ordering_holds({k: v for k, v in TABLE.items() if k != "VF"}) is None  # a variant missing: not judged
    # the release's four variants at λ 0.1 (no VF, VX_p): judged among those it has
    assert ordering_holds({"V": -0.02, "VX_t": 0.15, "VX": 0.23, "VFX": 0.27}, ("VFX", "VX", "VX_t", "V")) is True
    assert ordering_holds({"VX_t": 0.15, "VX": 0.23}, ("VX", "VX_t")) is None  # no variant without touch


def test_six_runs_at_the_stronger_weight_and_vfx_is_the_lambda_sweeps_run(tmp_path):
    c = map_config("tiny", out=str(tmp_path), experiments=("lambda", "lambda_factorial"), seeds=(0,),
                   variants=SIX)
    runs = lambda_factorial.specs(c)
    assert [s.train["variant"] for s in runs] == list(c.variants) and all("-lam0.1-" in s.name for s in runs)
    assert {s.train["sigreg_weight"] for s in runs} == {0.1}
    sweep = {s.name for s in all_specs(c) if s.experiment == "lambda"}
    assert len(sweep) == len(c.lambdas) and "VFX-h1-4-16-lam0.1-standard-s0" in sweep
    assert len(all_specs(c)) == len(c.lambdas) + len(c.variants) - 1  # VFX at λ 0.1 is trained once


def _results(tmp_path, log_k: dict) -> dict:
    c = map_config("tiny", out=str(tmp_path), experiments=("lambda_factorial",), seeds=(0,), variants=SIX)
    runs = {s.name: {"train": s.train, "probes": {"ridge": {"contact": {"log_k": log_k[s.train["variant"]],
                                                                         "log_m": 0.1, "object_pos": 0.9}}}}
            for s in lambda_factorial.specs(c)}
    return {"runs": runs, "experiments": {"lambda_factorial": list(runs)}, "certificates": {},
            "map_config": {"variants": list(c.variants)}}


def test_the_section_puts_ours_beside_the_release_and_says_whether_the_ordering_holds(tmp_path):
    text = "\n".join(lambda_factorial.lambda_factorial_table(_results(tmp_path, TABLE)))
    assert "## The factorial at λ = 0.1" in text
    assert "| VFX | +0.49 / +0.24 |" in text and "| VF | -0.01 / — |" in text  # the release has no VF at λ 0.1
    assert "ours holds; the release's runs (its VFX, VX, VX_t, V; seed means) holds." in text
    swapped = "\n".join(lambda_factorial.lambda_factorial_table(_results(tmp_path, {**TABLE, "VX_t": 0.0, "VF": 0.4})))
    assert "ours does not hold" in swapped
    assert lambda_factorial.lambda_factorial_table({"experiments": {}, "runs": {}}) == []


@pytest.mark.parametrize("log_k, verdict",
                         [(TABLE, REPRODUCED_AT_CPU), ({**TABLE, "VX_t": 0.0, "VF": 0.4}, NOT_REPRODUCED)])
def test_the_ledger_judges_the_ordering_from_a_records_six_runs(tmp_path, log_k, verdict):
    row = next(r for r in ROWS if r.id == "B21")
    assert ledger(tmp_path, (row,))["rows"][0]["verdict"] == NOT_RUN
    record = {"map_config": {"preset": "cpu", "environment": "reference"},
              "runs": {f"{v}-h1-4-16-lam0.1-standard-s0": {"probes": {"ridge": {"contact": {"log_k": k}}}}
                       for v, k in log_k.items()}}
    write_json(tmp_path / "findings_cpu_reference.json", record)
    assert ledger(tmp_path, (row,))["rows"][0]["verdict"] == verdict
    del record["runs"]["VF-h1-4-16-lam0.1-standard-s0"]  # five of six: the ordering is not judged
    write_json(tmp_path / "findings_cpu_reference.json", record)
    assert ledger(tmp_path, (row,))["rows"][0]["verdict"] == NOT_RUN
