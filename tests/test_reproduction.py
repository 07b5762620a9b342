"""The reproduction ledger (pokeworld.reproduction): verdicts computed on planted records, and the committed
docs/results/reproduction.{json,md} equal to what the committed records give now (so the ledger cannot go stale)."""

import json
import re
from pathlib import Path

import pytest

from pokeworld.experiments.factorial import FACTORIAL
from pokeworld.io import read_json, write_json
from pokeworld.published import paper as P
from pokeworld.reproduction import (
    NOT_REPRODUCED, NOT_RUN, R2, REPRODUCED, REPRODUCED_AT_CPU, ROWS, Cell, Derived, Read, Row, ledger,
    ledger_markdown, per_seed)

RESULTS = Path(__file__).resolve().parents[1] / "docs" / "results"
K = "runs/VFX-h1-4-16-lam0.02-standard-s{seed}/probes/ridge/contact/log_k"
VF_K = "runs/VF-h1-4-16-lam0.02-standard-s{seed}/probes/ridge/contact/log_k"


def plant(folder: Path, name: str, values: dict, preset: str = "paper", environment: str | None = "reference",
          variant: str = "VFX") -> None:
    """A small map record: ``values`` {seed: log k} of one variant's runs, under a map config naming ``preset`` and
    ``environment`` (None: a record that names none, i.e. the calibrated environment's)."""
    config = {"preset": preset, **({"environment": environment} if environment else {})}
    record = read_json(folder / name, "a planted record") if (folder / name).exists() else \
        {"map_config": config, "runs": {}}
    for seed, k in values.items():
        record["runs"][f"{variant}-h1-4-16-lam0.02-standard-s{seed}"] = {"probes": {"ridge": {"contact": {"log_k": k}}}}
    write_json(folder / name, record)


def one_row(paper=0.50, paper_record="paper.json", cpu_record="cpu.json", released=None, path=K) -> tuple[Row, ...]:
    cell = Cell("VFX log k", paper, R2, Read(paper_record, path), Read(cpu_record, path), released=released)
    return (Row("X1", "targets", "Table \"targets\"", "VFX log k", (cell,), cause="the planted cause",
                needs="a planted need"),)


def verdict_of(folder: Path, rows) -> dict:
    return ledger(folder, rows)["rows"][0]


def test_within_tolerance_at_the_paper_budget_is_reproduced(tmp_path):
    plant(tmp_path, "paper.json", {0: 0.55})
    row = verdict_of(tmp_path, one_row())
    assert row["verdict"] == REPRODUCED
    assert "cause" not in row and "needs" not in row
    assert row["cells"][0]["paper_budget"]["read"] == [{"record": "paper.json", "path": K}]


def test_outside_tolerance_is_not_reproduced_with_its_cause(tmp_path):
    plant(tmp_path, "paper.json", {0: 0.30})
    plant(tmp_path, "cpu.json", {0: 0.50, 1: 0.50}, preset="cpu")
    row = verdict_of(tmp_path, one_row())
    assert row["verdict"] == NOT_REPRODUCED
    assert row["cause"] == "the planted cause" and row["measured_at"] == "paper budget"  # the paper's budget decides
    assert row["outside"] and "0.30 vs 0.50" in row["outside"][0]


def test_a_missing_record_or_run_is_not_run_with_what_it_needs(tmp_path):
    row = verdict_of(tmp_path, one_row())
    assert row["verdict"] == NOT_RUN and row["needs"] == "a planted need" and "cause" not in row
    plant(tmp_path, "paper.json", {0: 0.50}, variant="VF")  # the record exists, the run does not
    assert verdict_of(tmp_path, one_row())["verdict"] == NOT_RUN


def test_a_calibrated_record_never_counts_as_a_default_environment_reproduction(tmp_path):
    plant(tmp_path, "paper.json", {0: 0.50}, environment=None)  # names no environment: the calibrated one
    row = verdict_of(tmp_path, one_row())
    assert row["verdict"] == NOT_RUN
    assert row["cells"][0]["paper_budget"]["environment"] == "calibrated"
    assert row["cells"][0]["state"]["paper_budget"] is None
    plant(tmp_path, "cpu.json", {0: 0.48}, preset="cpu", environment="calibrated")
    row = verdict_of(tmp_path, one_row())
    assert row["verdict"] == REPRODUCED_AT_CPU and row["environment"] == "calibrated (retired)"
    md = ledger_markdown(ledger(tmp_path, one_row()))
    assert "calibrated environment (retired)" in md and "not counted at the paper budget" in md


def test_a_run_cut_short_does_not_count_at_the_paper_budget(tmp_path):
    plant(tmp_path, "paper.json", {0: 0.50})
    record = read_json(tmp_path / "paper.json", "a planted record")
    record["runs"]["VFX-h1-4-16-lam0.02-standard-s0"]["allocation"] = {"steps": 20000, "steps_trained": 19429}
    write_json(tmp_path / "paper.json", record)
    row = verdict_of(tmp_path, one_row())
    assert row["verdict"] == NOT_RUN and "cut short" in row["cells"][0]["paper_budget"]["budget"]


def test_cpu_within_tolerance_on_the_reference_environment_is_reproduced_at_cpu_only(tmp_path):
    plant(tmp_path, "cpu.json", {0: 0.45, 1: 0.47}, preset="cpu")
    row = verdict_of(tmp_path, one_row())
    assert row["verdict"] == REPRODUCED_AT_CPU and row["environment"] == "reference"
    assert row["cells"][0]["cpu"]["seeds"] == [0, 1] and row["cells"][0]["cpu"]["value"] == pytest.approx(0.46)


def test_a_per_seed_paper_value_is_compared_over_our_seeds_and_runs_added_later_are_read(tmp_path):
    rows = one_row(paper=per_seed((0.40, 0.60)))
    plant(tmp_path, "paper.json", {0: 0.31})  # within 0.1 of s0's 0.40, not of the two seeds' mean 0.50
    assert verdict_of(tmp_path, rows)["verdict"] == REPRODUCED
    plant(tmp_path, "paper.json", {1: 0.31})  # a second seed lands in the same record: its paper value is 0.60
    row = verdict_of(tmp_path, rows)
    assert row["verdict"] == NOT_REPRODUCED and row["cells"][0]["paper_budget"]["seeds"] == [0, 1]


def test_a_row_is_judged_at_one_budget_and_against_the_release_where_they_differ(tmp_path):
    two = (Cell("VFX", 0.50, R2, Read("paper.json", K), Read("cpu.json", K)),
           Cell("VF", 0.00, R2, Read("paper.json", VF_K), Read("cpu.json", VF_K)))
    rows = (Row("X2", "targets", "s", "two cells", two, cause="c"),)
    plant(tmp_path, "paper.json", {0: 0.52})  # VFX at the paper budget; VF only at cpu
    plant(tmp_path, "cpu.json", {0: 0.30}, preset="cpu", variant="VFX")
    plant(tmp_path, "cpu.json", {0: 0.05}, preset="cpu", variant="VF")
    assert verdict_of(tmp_path, rows)["verdict"] == NOT_REPRODUCED  # the cpu budget judges the whole row
    assert "against_release" not in verdict_of(tmp_path, one_row(paper=0.50, released={0: 0.49}))  # they agree
    row = verdict_of(tmp_path, one_row(paper=0.90, released={0: 0.55}))  # ours 0.52: the release's, not the paper's
    assert row["verdict"] == NOT_REPRODUCED and row["against_release"] == REPRODUCED
    row = verdict_of(tmp_path, one_row(paper=0.20, released={0: 0.80}))
    assert row["verdict"] == NOT_REPRODUCED and row["against_release"] == NOT_REPRODUCED


def test_derived_values_need_their_parts(tmp_path):
    contrast = Derived("difference", (Read("paper.json", K), Read("paper.json", VF_K)))
    best = Derived("max", (Read("paper.json", K), Read("paper.json", "runs/absent/log_k")))
    rows = (Row("X3", "targets", "s", "contrast", (Cell("VFX − VF", 0.50, R2, contrast),
                                                   Cell("best", 0.50, R2, best))),)
    plant(tmp_path, "paper.json", {0: 0.52})
    assert verdict_of(tmp_path, rows)["verdict"] == NOT_RUN  # the difference lacks VF; max takes what is there
    plant(tmp_path, "paper.json", {0: 0.02}, variant="VF")
    row = verdict_of(tmp_path, rows)
    assert row["verdict"] == REPRODUCED and row["cells"][0]["paper_budget"]["value"] == pytest.approx(0.50)


def test_the_report_shows_a_cause_only_when_not_reproduced_and_never_the_paper_in_our_columns(tmp_path):
    plant(tmp_path, "paper.json", {0: 0.55})
    md = ledger_markdown(ledger(tmp_path, one_row(paper=0.77)))
    line = next(x for x in md.splitlines() if x.startswith("| X1 "))
    cells = [c.strip() for c in line.split("|")[1:-1]]
    assert cells[2] == "0.77" and cells[4].startswith("0.55 ") and "0.77" not in cells[4] + cells[5]
    assert "the planted cause" in cells[7]
    assert "the planted cause" not in ledger_markdown(ledger(tmp_path, one_row(paper=0.55)))


# ----------------------------------------------------------------------------- the committed ledger


def test_the_rows_are_the_inventorys_75():
    ids = [r.id for r in ROWS]
    expected = ([f"A{i}" for i in range(1, 9)] + [f"B{i}" for i in range(1, 25)] + [f"C{i}" for i in range(1, 5)]
                + ["D1", "D2"] + [f"E{i}" for i in range(1, 25)] + ["F1", "F2", "G1"] + [f"H{i}" for i in range(1, 11)])
    assert sorted(ids) == sorted(expected) and len(ids) == len(set(ids)) == 75
    assert all(r.cells for r in ROWS)


def test_the_per_seed_table_is_the_factorials_means():
    for variant, qs in P.TARGETS_PER_SEED.items():
        for q, (s0, s1) in qs.items():
            assert (s0 + s1) / 2 == pytest.approx(FACTORIAL[variant][q])


def test_the_committed_ledger_is_what_the_committed_records_give():
    committed = read_json(RESULTS / "reproduction.json", "the committed reproduction ledger")
    now = json.loads(json.dumps(ledger(RESULTS)))
    assert now == committed, "docs/results/reproduction.json is stale: run python scripts/reproduction_ledger.py"
    md = (RESULTS / "reproduction.md").read_text(encoding="utf-8")
    assert md == ledger_markdown(committed), "docs/results/reproduction.md is stale: run the same script"
    summary = re.search(r"\*\*75 rows: (\d+) reproduced · (\d+) reproduced at cpu only", md)
    assert summary and int(summary[1]) == committed["counts"]["reproduced"]


def test_readmes_counts_are_the_ledgers():
    """README's headline states the generated ledger's counts, never its own."""
    import json
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    counts = json.loads((root / "docs" / "results" / "reproduction.json").read_text())["counts"]
    text = " ".join((root / "README.md").read_text().split())
    m = re.search(r"Of the paper's (\d+) quantitative results, (\d+) are reproduced at its budget, (\d+) at `cpu` "
                  r"only, (\d+) are not \(each with its measured cause\) and (\d+) are not run", text)
    assert m, "README's headline does not state the ledger's counts"
    total, ok, cpu, bad, not_run = map(int, m.groups())
    assert (ok, cpu, bad, not_run) == (counts["reproduced"], counts["reproduced at cpu only"],
                                       counts["not reproduced"], counts["not run"])
    assert total == sum(counts.values())


def test_at_cpu_the_reference_environments_record_comes_before_the_retired_one(tmp_path):
    """A cpu cell reads the reference environment's record of every experiment when it holds the run, else the
    calibrated one's, which the row then names as the retired environment's."""
    from pokeworld.reproduction import at_cpu

    rows = lambda: (Row("X2", "targets", "planted", "VFX log k",  # noqa: E731
                        (Cell("VFX log k", 0.50, R2, None, at_cpu("old.json", K)),)),)
    plant(tmp_path, "old.json", {0: 0.48}, preset="cpu", environment=None)  # the retired calibrated environment's
    row = verdict_of(tmp_path, rows())
    assert row["verdict"] == REPRODUCED_AT_CPU and row["environment"] == "calibrated (retired)"
    assert row["cells"][0]["cpu"]["read"] == [{"record": "old.json", "path": K}]
    plant(tmp_path, "findings_cpu_reference.json", {0: 0.20}, preset="cpu")
    row = verdict_of(tmp_path, rows())
    assert row["verdict"] == NOT_REPRODUCED and row["cells"][0]["cpu"]["environment"] == "reference"
    assert row["cells"][0]["cpu"]["read"] == [{"record": "findings_cpu_reference.json", "path": K}]


def test_a_row_reads_one_environment_at_cpu_until_the_default_record_holds_all_its_runs(tmp_path):
    """A dose–response whose default run is in the reference environment's record and whose other weights are only
    in the retired one's reads the retired record for every cell; once the reference record holds them all, it
    reads that one for every cell."""
    from pokeworld.reproduction import at_cpu

    cells = (Cell("VFX log k", 0.50, R2, None, at_cpu("old.json", K)),
             Cell("VF log k", 0.00, R2, None, at_cpu("old.json", VF_K)))
    rows = (Row("X3", "frontier", "planted", "two runs", cells),)
    plant(tmp_path, "old.json", {0: 0.48}, preset="cpu", environment=None)
    plant(tmp_path, "old.json", {0: 0.02}, preset="cpu", environment=None, variant="VF")
    plant(tmp_path, "findings_cpu_reference.json", {0: 0.20}, preset="cpu")  # VFX only: VF not yet re-run
    row = verdict_of(tmp_path, rows)
    assert [c["cpu"]["read"][0]["record"] for c in row["cells"]] == ["old.json", "old.json"]
    assert row["verdict"] == REPRODUCED_AT_CPU and row["environment"] == "calibrated (retired)"
    plant(tmp_path, "findings_cpu_reference.json", {0: 0.05}, preset="cpu", variant="VF")
    row = verdict_of(tmp_path, rows)
    assert [c["cpu"]["read"][0]["record"] for c in row["cells"]] == ["findings_cpu_reference.json"] * 2
    assert row["verdict"] == NOT_REPRODUCED  # the reference record's VFX (0.20) is outside 0.50 ± 0.1
