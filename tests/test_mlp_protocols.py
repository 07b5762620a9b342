"""The released MLP probe's protocol (one network for three parameters, kept at the best mean validation R²) on
planted signals: where it reads a signal, and where its selection rule reads a planted one at chance."""

import numpy as np
import pytest

from pokeworld.errors import DataError
from pokeworld.evaluate.mlp_protocols import JointMLPProbe, protocol_scores, selection_runs, selection_stability
from pokeworld.regressors import r2_scores


def planted(n, d, shares, seed):
    """X (n, d) Gaussian; target j = sqrt(share_j) X[:, j] + noise, so a linear readout's R² is share_j."""
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, d))
    Y = np.stack([np.sqrt(s) * X[:, j] + np.sqrt(1 - s) * rng.normal(size=n) for j, s in enumerate(shares)], 1)
    return X, Y


def test_joint_probe_reads_planted_signals_when_it_can_learn_them():
    X, Y = planted(6000, 4, (0.6, 0.5, 0.4), 0)
    Xt, Yt = planted(2000, 4, (0.6, 0.5, 0.4), 1)
    out = JointMLPProbe(steps=801, seed=0).fit_predict(X, Y, np.arange(6000) // 4, Xt)
    r2 = r2_scores(Yt, out["mean"])
    assert np.allclose(r2, (0.6, 0.5, 0.4), atol=0.06)
    assert out["mean_step"] > 0


def test_mean_rule_reads_a_planted_signal_at_chance_where_the_per_parameter_probe_reads_it():
    # one parameter with signal, two without, few windows per dimension: the network fits the two noise
    # targets' training rows, their validation R² falls below zero, and the mean over three is best at step 0
    X, Y = planted(1500, 64, (0.3, 0.0, 0.0), 2)
    Xt, Yt = planted(800, 64, (0.3, 0.0, 0.0), 3)
    g = np.arange(1500) // 5
    names = ("log_m", "gamma", "log_k")
    res = protocol_scores(X, g, {n: Y[:, [j]] for j, n in enumerate(names)}, Xt,
                          {n: Yt[:, [j]] for j, n in enumerate(names)}, joint=JointMLPProbe(steps=801))
    assert res["joint_steps"]["mean"] == 0
    assert abs(res["r2"]["mlp_joint_mean"]["log_m"]) < 0.05
    assert res["r2"]["ridge"]["log_m"] == pytest.approx(0.3, abs=0.06)
    assert res["r2"]["mlp_per_parameter"]["log_m"] > 0.15


def test_each_rule_keeps_every_parameter_at_its_own_best_step():
    X, Y = planted(3000, 4, (0.5, 0.0, 0.0), 4)
    Xt, _ = planted(500, 4, (0.5, 0.0, 0.0), 5)
    out = JointMLPProbe(steps=401, every=100, seed=0).fit_predict(X, Y, np.arange(3000) // 3, Xt)
    assert len(out["each_step"]) == 3 and all(s % 100 == 0 for s in out["each_step"])
    assert out["each"].shape == out["mean"].shape == (500, 3)


def test_bad_input_is_one_clear_error():
    with pytest.raises(DataError, match="steps"):
        JointMLPProbe(steps=0)
    X, Y = planted(100, 3, (0.5,), 0)
    with pytest.raises(DataError, match="two episodes"):
        JointMLPProbe(steps=1).fit_predict(X, Y, np.zeros(100, int), X)
    Y[0, 0] = np.nan
    with pytest.raises(DataError, match="finite"):
        JointMLPProbe(steps=1).fit_predict(X, Y, np.arange(100), X)


def test_the_curve_is_what_the_mean_rule_chose_from():
    X, Y = planted(3000, 4, (0.5, 0.2, 0.0), 6)
    Xt, _ = planted(300, 4, (0.5, 0.2, 0.0), 7)
    out = JointMLPProbe(steps=401, every=100, seed=0).fit_predict(X, Y, np.arange(3000) // 3, Xt)
    assert [c["step"] for c in out["curve"]] == [0, 100, 200, 300, 400]
    means = [np.mean(c["val_r2"]) for c in out["curve"]]
    assert out["curve"][int(np.argmax(means))]["step"] == out["mean_step"]


def test_seed_sweep_separates_a_learnable_signal_from_a_selection_draw():
    names = ("log_m", "gamma", "log_k")
    # three learnable signals: no probe seed keeps step 0, every seed reads them
    X, Y = planted(4000, 4, (0.6, 0.5, 0.4), 8)
    Xt, Yt = planted(1000, 4, (0.6, 0.5, 0.4), 9)
    easy = selection_runs(X, np.arange(4000) // 4, Y, Xt, Yt, seeds=3, names=names, steps=401)
    assert easy["kept_step_0"] == 0 and easy["r2_range"]["log_m"][0] > 0.5
    assert all(r["val_margin_over_step0"] > 0 for r in easy["runs"])
    # one weak signal beside two empty targets and few windows per dimension: the rule keeps step 0 (margin 0) and
    # reads log m at chance, the case the release's single seed cannot tell from an unreadable parameter
    X, Y = planted(1500, 64, (0.3, 0.0, 0.0), 2)
    Xt, Yt = planted(800, 64, (0.3, 0.0, 0.0), 3)
    hard = selection_runs(X, np.arange(1500) // 5, Y, Xt, Yt, seeds=3, names=names, steps=801)
    assert hard["kept_step_0"] >= 1
    for r in hard["runs"]:
        assert (r["kept_step"] == 0) == (r["val_margin_over_step0"] == 0)
        if r["kept_step"] == 0:
            assert abs(r["r2"]["log_m"]) < 0.05
    with pytest.raises(DataError, match="probe seed"):
        selection_runs(X, np.arange(1500) // 5, Y, Xt, Yt, seeds=0, names=names)


def test_validation_blocks_move_back_from_the_release_split_and_stop_at_the_first_episode():
    g = np.repeat(np.arange(20), 3)
    last = JointMLPProbe(val_fraction=0.25).split(g)
    assert set(g[last]) == {15, 16, 17, 18, 19}  # the release's: the last quarter of the episodes
    assert set(g[JointMLPProbe(val_fraction=0.25, val_block=3).split(g)]) == {0, 1, 2, 3, 4}
    with pytest.raises(DataError, match="validation block 4"):
        JointMLPProbe(val_fraction=0.25, val_block=4).split(g)


def test_stability_reads_ridge_beside_both_draws_on_one_set_of_states(monkeypatch):
    names = ("log_m", "gamma", "log_k")
    X, Y = planted(2000, 4, (0.6, 0.5, 0.4), 10)
    Xt, Yt = planted(500, 4, (0.6, 0.5, 0.4), 11)
    states = {"Xf": X, "gf": np.arange(2000) // 4, "Yf": Y, "Xt": Xt, "Yt": Yt, "names": names,
              "counts": {"fit": 2000, "test": 500}}
    import pokeworld.evaluate.mlp_protocols as mp

    real = mp.selection_runs
    monkeypatch.setattr(mp, "selection_runs", lambda *a, **k: real(*a, **{**k, "steps": 201}))  # 4,001: minutes
    out = selection_stability(states, seeds=2, blocks=2)
    assert out["seeds"] == 2 and out["vary"] == "seed" and out["validation"]["vary"] == "validation"
    assert [r["seed"] for r in out["validation"]["runs"]] == [0, 1]
    assert out["ridge"]["log_m"] == pytest.approx(0.6, abs=0.06) and out["counts"]["test"] == 500


def test_the_script_refuses_to_merge_into_a_record_of_another_store(tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    from pokeworld.cli import main
    from pokeworld.io import write_json

    store = tmp_path / "store"
    assert main(["generate", "--preset", "tiny", str(store)]) == 0
    record = tmp_path / "rec.json"  # an earlier record of this script, written as the script writes it
    write_json(record, {"data": {"name": "standard", "content_sha256": "45f50da1" + "0" * 56}, "models": []})
    root = Path(__file__).resolve().parents[1]
    proc = subprocess.run([sys.executable, "scripts/mlp_probe_protocols.py", str(tmp_path / "no-model"), "--data",
                           str(store), "--preset", "tiny", "--out", str(record)], cwd=root, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 2 and "another store" in proc.stderr and proc.stderr.count("\n") == 1
    proc = subprocess.run([sys.executable, "scripts/mlp_probe_protocols.py", "m", "--data", str(store),
                           "--probe-seeds", "-1"], cwd=root, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and "--probe-seeds" in proc.stderr
