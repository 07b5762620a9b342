"""The planning experiment inside the map: it reuses the factorial's runs, writes the table, figure and results."""

import json

import pytest

from pokeworld import experiments as experiment
from pokeworld.experiments import factorial, planning


def test_planning_reuses_the_factorial_runs():
    c = experiment.make_config("cpu", experiments=("factorial", "planning"))
    names = [s.name for s in experiment.all_specs(c)]
    factorial_runs = {s.name for s in factorial.specs(c)}
    assert {s.name for s in planning.specs(c)} <= factorial_runs  # no extra training
    assert len(names) == len(set(names)) == len(factorial_runs)
    alone = experiment.make_config("cpu", experiments=("planning",))
    assert {s.name for s in experiment.all_specs(alone)} == {
        f"{v}-h1-4-16-lam0.02-standard-s0" for v in ("V", "VX_t", "VX_p", "VFX")}


@pytest.mark.slow
def test_tiny_map_with_planning_writes_the_table(tmp_path, capsys):
    out = tmp_path / "map"
    c = experiment.make_config("tiny", out=str(out), workers=1, experiments=("factorial", "planning"),
                               planning_variants=("V", "VX_t"))
    experiment.run(c)
    res = json.loads((out / "results.json").read_text())
    summary = res["planning"]["summary"]
    assert set(summary) == {"random", "V", "VX_t"}
    for v in summary.values():
        assert 0.0 <= v["reach"] <= 1.0 and isinstance(v["median_improvement"], float)
    assert set(summary["V"]["per_run"]) == {"V-h1-4-16-lam0.02-standard-s0"}
    assert set(res["runs"]) == {"V-h1-4-16-lam0.02-standard-s0", "VX_t-h1-4-16-lam0.02-standard-s0"}
    assert (out / "planning" / "plan_episode.png").exists()
    md = (out / "results.md").read_text()
    assert "## Closed-loop planning" in md
    assert "| VX_t |" in md and "/ 38% |" in md and "| random |" in md  # paper beside ours
    capsys.readouterr()
    experiment.run(c)
    assert "skipping planning" in capsys.readouterr().out
    _rollout_scorer_composes_the_one_step_head(out / "runs" / "V-h1-4-16-lam0.02-standard-s0")


def _rollout_scorer_composes_the_one_step_head(run):
    """heads='rollout' scores a program by the model's own autoregressive rollout through it (checked against
    XJEPA.rollout called directly), and predicts something other than the direct heads."""
    import numpy as np
    import torch

    from pokeworld import plan

    cfg = plan.make_config("tiny")
    sim, obs = plan.start_sim(cfg, plan.episode_setup(cfg))
    hist = {"frames": obs["vision"][:, None, ..., 0], "proprio": obs["proprio"][:, None], "touch": obs["touch"][:, None],
            "actions": np.zeros((cfg.episodes, 0, 2), np.float32)}
    cand = plan.rank_candidates(cfg)
    direct, roll = plan.LatentScorer(str(run), ""), plan.LatentScorer(str(run), "", heads="rollout")
    pd, pr = direct.positions(hist, cand), roll.positions(hist, cand)
    assert pd[16].shape == pr[16].shape == (cfg.episodes, cfg.population, 2)
    assert not np.allclose(pd[16], pr[16])
    m = roll.model
    with torch.no_grad():
        z = m.encode(hist["frames"], hist["proprio"], hist["touch"])  # every start, each with its first candidate
        zr = m.rollout(z, cand[:, 0].astype(np.float32), 16, actions_context=hist["actions"])
    np.testing.assert_allclose(roll.decoder.predict(zr[:, 15].numpy()), pr[16][:, 0], rtol=1e-4, atol=1e-4)
    # the approach term's device path (decoders folded into affine maps, costs beside the latents) equals the
    # host's numpy path, and the term changes the costs
    shaped = plan.LatentScorer(str(run), "", approach=(0.4, 0.18))
    goal = plan.episode_setup(cfg)["goal"]
    host = shaped.score(hist, cand, goal)
    np.testing.assert_allclose(shaped.device_score(hist, cand, goal), host, rtol=1e-4, atol=1e-4)
    assert not np.allclose(host, direct.score(hist, cand, goal))
    with pytest.raises(Exception, match="heads must be one of"):
        plan.make_config("tiny", heads="lookahead")
