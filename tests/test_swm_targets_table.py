"""The cross-environment targets table: verdicts on planted factorials, the records it accepts, what it writes."""

import json

import pytest

from pokeworld.errors import ConfigError, DataError
from pokeworld.swm import factorial as X, targets_table as T


def planted_record(env: str, ridge: dict[str, dict[str, list[float]]], gate: dict[str, bool]) -> dict:
    """An swm-certify record whose factorial has, per factor and variant, the given ridge R² at seeds 0 and 1."""
    runs = {v: {str(s): {"steps": 100, "factors": {q: {"ridge": cells[v][s], "mlp": cells[v][s], "untrained": 0.0}
                                                   for q, cells in ridge.items()}}
                for s in (0, 1)} for v in X.SWM_VARIANTS}
    gates = {q: {"certificate": 0.9 if ok else 0.0, "threshold": 0.4, "gate_passed": ok} for q, ok in gate.items()}
    return {"env": env, "command": f"pokeworld swm-certify {env}", "corpus": {"episodes": 10},
            "config": {"policy": "random"},
            "xjepa": {"variants": runs, "summary": X.summary(runs, gates), "preset": "tiny", "seeds": [0, 1]}}


def flat(value: float) -> list[float]:
    return [value, value]


TARGET = {"V": flat(0.0), "VF": flat(0.0), "VX": [0.5, 0.4], "VFX": [0.6, 0.5]}
INPUT = {"V": flat(0.1), "VF": [0.7, 0.6], "VX": flat(0.1), "VFX": [0.7, 0.6]}
BOTH = {"V": flat(0.0), "VF": flat(0.4), "VX": flat(0.4), "VFX": flat(0.8)}
NOTHING = {"V": flat(0.05), "VF": flat(0.07), "VX": flat(0.1), "VFX": flat(0.07)}
SPLIT = {"V": flat(0.0), "VF": flat(0.0), "VX": [0.6, -0.05], "VFX": [0.6, -0.05]}  # one seed only
VISION = {"V": [0.7, 0.65], "VF": flat(0.72), "VX": flat(0.73), "VFX": flat(0.75)}  # untrained twins at 0


def test_verdicts_on_planted_factorials():
    rec = planted_record("swm/A", {"g": TARGET, "m": INPUT, "b": BOTH, "n": NOTHING, "s": SPLIT, "x": TARGET,
                                   "v": VISION}, {"g": True, "m": True, "b": True, "n": True, "s": True, "x": False,
                                                  "v": True})
    summary = T.summarise({"a.json": rec})
    got = {r["factor"]: r["verdict"] for r in summary["rows"]}
    assert got == {"g": "target", "m": "input", "b": "both", "n": "neither", "s": "neither", "x": "no claim",
                   "v": "vision alone"}
    rec["factor_effects"] = {"x": {"inert": True}, "g": {"inert": False}}
    again = {r["factor"]: r["verdict"] for r in T.summarise({"a.json": rec})["rows"]}
    assert again["x"] == "no claim (inert)" and again["g"] == "target"
    g = next(r for r in summary["rows"] if r["factor"] == "g")
    assert g["effects_per_seed"]["target_without_input"] == pytest.approx({"0": 0.5, "1": 0.4})
    assert g["effects_ridge"]["target_with_input"] == pytest.approx(0.55)
    assert summary["certified"] == {"factors": 6, "environments": 1}


def test_run_writes_the_table_of_two_environments(tmp_path):
    paths = []
    for env, planted in (("swm/A", {"g": TARGET}), ("swm/B", {"m": INPUT})):
        p = tmp_path / f"{env.split('/')[1]}.json"
        p.write_text(json.dumps(planted_record(env, planted, {q: True for q in planted})))
        paths.append(str(p))
    out = T.run(T.TargetsConfig(records=tuple(paths), out=str(tmp_path / "res" / "targets")))
    assert out == tmp_path / "res" / "targets.md"
    summary = json.loads((tmp_path / "res" / "targets.json").read_text())
    assert summary["verdicts"] == {"swm/A g": "target", "swm/B m": "input"}
    assert summary["certified"] == {"factors": 2, "environments": 2}
    md = out.read_text()
    assert "| swm/A | g |" in md and "| target |" in md and "| input |" in md
    assert (tmp_path / "res" / "targets.png").stat().st_size > 0
    T.run(T.TargetsConfig(records=tuple(paths), out=str(tmp_path / "res" / "targets")))  # its own files: replaced


def test_refuses_records_without_a_factorial_and_a_users_file(tmp_path):
    bare = tmp_path / "bare.json"
    bare.write_text(json.dumps({"env": "swm/A", "factors": {}}))
    with pytest.raises(DataError, match="no X-JEPA factorial"):
        T.load_factorial(bare)
    part = planted_record("swm/A", {"g": TARGET}, {"g": True})
    del part["xjepa"]["variants"]["VX"]
    (tmp_path / "part.json").write_text(json.dumps(part))
    with pytest.raises(DataError, match=r"lacks variants \['VX'\]"):
        T.load_factorial(tmp_path / "part.json")
    with pytest.raises(ConfigError, match="--records is empty"):
        T.run(T.TargetsConfig(records=(), out=str(tmp_path / "t")))
    good = tmp_path / "good.json"
    good.write_text(json.dumps(planted_record("swm/A", {"g": TARGET}, {"g": True})))
    mine = tmp_path / "t.md"
    mine.write_text("a user's notes")
    with pytest.raises(ConfigError):
        T.run(T.TargetsConfig(records=(str(good),), out=str(tmp_path / "t")))
    assert mine.read_text() == "a user's notes" and not (tmp_path / "t.json").exists()
