"""stable-worldmodel's LeWM on PokeWorld: its own objective trains, the adapter obeys the protocol's contract,
runs resume bit-for-bit and are reused when finished, checkpoints load weights-only."""

import json

import numpy as np
import pytest
import torch

from pokeworld.data import save
from pokeworld.errors import ConfigError
from pokeworld.io import read_jsonl
from pokeworld.swm import lewm as L


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    """72 episodes at 16 px with train / probe-fit / probe-test episodes, written as a real store."""
    from pokeworld.sim.generate import make_config as gen_config, simulate

    ds = simulate(gen_config("tiny", num_episodes=72, batch_envs=72, split_fractions=(0.4, 0.3, 0.3),
                             physics={"image_size": 16}), progress=False)
    return save(ds, tmp_path_factory.mktemp("lewm") / "store")


def tiny(store, out, **kw) -> L.LeWMConfig:
    return L.make_config("tiny", data=str(store), out=str(out), **kw)


def test_lewm_objective_decreases_on_a_tiny_store(store, tmp_path):
    cfg = tiny(store, tmp_path / "run", steps=80)
    L.train(cfg)
    rows = read_jsonl(tmp_path / "run" / "metrics.jsonl")
    assert [r["step"] for r in rows] == list(range(5, 81, 5))
    assert all(np.isfinite([r["loss"], r["pred_loss"], r["sigreg_loss"]]).all() for r in rows)
    first, last = np.mean([r["loss"] for r in rows[:2]]), np.mean([r["loss"] for r in rows[-2:]])
    assert last < 0.7 * first, (first, last)
    # the logged total is LeWM's: pred_loss + λ · SIGReg
    r = rows[-1]
    assert r["loss"] == pytest.approx(r["pred_loss"] + cfg.sigreg_weight * r["sigreg_loss"], rel=1e-4)
    assert json.loads((tmp_path / "run" / "config.json").read_text())["steps"] == 80


def test_interrupted_run_resumes_to_the_same_weights(store, tmp_path, monkeypatch):
    whole = tiny(store, tmp_path / "whole", steps=40, ckpt_every=10)
    L.train(whole)
    cut = tiny(store, tmp_path / "cut", steps=40, ckpt_every=10)
    calls = {"n": 0}
    real_loss = L.lewm_loss

    def dies_at_step_25(*a, **kw):
        calls["n"] += 1
        if calls["n"] == 26:
            raise RuntimeError("killed")
        return real_loss(*a, **kw)

    monkeypatch.setattr(L, "lewm_loss", dies_at_step_25)
    with pytest.raises(RuntimeError, match="killed"):
        L.train(cut)
    assert torch.load(tmp_path / "cut" / "ckpt.pt", weights_only=True)["step"] == 20
    assert not L.is_trained(tmp_path / "cut", cut)
    monkeypatch.setattr(L, "lewm_loss", real_loss)
    L.train(cut)
    a = torch.load(tmp_path / "whole" / "ckpt.pt", weights_only=True)
    b = torch.load(tmp_path / "cut" / "ckpt.pt", weights_only=True)
    assert a["step"] == b["step"] == 40 and a["done"] and b["done"]
    for k in a["model"]:
        assert torch.equal(a["model"][k], b["model"][k]), k
    strip = lambda rows: [{k: v for k, v in r.items() if k != "seconds"} for r in rows]  # noqa: E731
    assert strip(read_jsonl(tmp_path / "cut" / "metrics.jsonl")) == strip(read_jsonl(tmp_path / "whole" / "metrics.jsonl"))


def test_finished_run_is_reused_and_a_changed_config_is_refused(store, tmp_path, capsys):
    cfg = tiny(store, tmp_path / "run", steps=10)
    L.train(cfg)
    ckpt = tmp_path / "run" / "ckpt.pt"
    stamp = ckpt.stat().st_mtime_ns
    L.train(L.make_config("tiny", data=str(store), out=str(tmp_path / "run"), steps=10, readout="both"))
    assert ckpt.stat().st_mtime_ns == stamp and "reusing" in capsys.readouterr().out
    with pytest.raises(ConfigError, match="lr"):
        L.train(tiny(store, tmp_path / "run", steps=10, lr=1e-4))


def test_checkpoint_loads_weights_only_and_the_twin_is_the_untrained_init(store, tmp_path):
    from pokeworld.data import load

    cfg = tiny(store, tmp_path / "run", steps=10)
    L.train(cfg)
    ck = torch.load(tmp_path / "run" / "ckpt.pt", weights_only=True)
    assert set(ck) >= {"model", "optimizer", "rng", "sampler", "step", "config"} and ck["config"]["steps"] == 10
    ds = load(store)
    trained, twin, again = L.load_trained(tmp_path / "run", cfg, ds), L.build_model(cfg, ds), L.build_model(cfg, ds)
    assert all(torch.equal(v, again.state_dict()[k]) for k, v in twin.state_dict().items())
    moved = [k for k, v in twin.state_dict().items() if v.is_floating_point() and not torch.equal(v, trained.state_dict()[k])]
    assert any(k.startswith("encoder.") for k in moved) and any(k.startswith("predictor.") for k in moved)
    assert all(torch.equal(twin.state_dict()[k], trained.state_dict()[k]) for k in ("actions_mean", "proprio_std"))


@pytest.mark.parametrize("readout,width", [("predictor", 32), ("embedding", 32), ("both", 64)])
def test_states_obey_the_contract_and_are_causal(store, readout, width):
    from pokeworld.data import load

    ds = load(store)
    model = L.LeWMStates(L.build_model(L.make_config("tiny"), ds), readout)
    model.eval()
    e = np.arange(6)
    frames, proprio, touch = ds.frames[e, :12], ds.proprio[e, :12], ds.touch[e, :12]
    acts = np.concatenate([ds.actions, np.zeros_like(ds.actions[:, :1])], 1)[e, :12]
    with torch.no_grad():
        s = model(*(torch.from_numpy(np.ascontiguousarray(x)) for x in (frames, proprio, touch, acts)))
        assert s.shape == (6, 12, width) and torch.isfinite(s).all()
        later = frames.copy()
        later[:, 8:] = 255 - later[:, 8:]  # change only what comes after observation 7
        s2 = model(*(torch.from_numpy(np.ascontiguousarray(x)) for x in (later, proprio, touch, acts)))
    assert torch.allclose(s[:, :8], s2[:, :8], atol=1e-5) and not torch.allclose(s[:, 8:], s2[:, 8:])


def test_run_trains_then_certifies_beside_the_untrained_twin(store, tmp_path):
    cfg = tiny(store, tmp_path / "run", steps=20,
               protocol_overrides={"kinds": ("contact", "all"), "certify_estimators": ("gru", "linear")})
    summary = L.run(cfg)
    rep = json.loads((tmp_path / "run" / "protocol" / "protocol.json").read_text())
    assert rep["model"]["state_dim"] == cfg.embed_dim and "untrained" in rep
    assert set(summary["r2"]) == {"contact", "all"}
    cell = summary["r2"]["contact"]["log_m"]
    assert np.isfinite(cell["ridge"]) and np.isfinite(cell["untrained_ridge"])
    assert cell["ridge"] == rep["probes"]["ridge"]["contact"]["log_m"]
    assert set(summary["gate"]) == {"log_m", "gamma", "log_k"}
    assert (tmp_path / "run" / "summary.json").exists() and (tmp_path / "run" / "protocol" / "protocol.md").exists()


def test_compare_runs_certify_an_xjepa_run_beside_the_lewm_with_the_same_probes(store, tmp_path):
    """compare_runs: a tiny X-JEPA run on the same store is certified through the same ProtocolConfig, and the
    comparison table holds both models' numbers exactly as their own protocol reports give them."""
    from pokeworld.train import make_config as train_config, run as train_run

    xjepa = tmp_path / "VFX"
    train_run(train_config("tiny", variant="VFX", data=str(store), out=str(xjepa), steps=4))
    cfg = tiny(store, tmp_path / "run", steps=10, compare_runs=(str(xjepa),),
               protocol_overrides={"kinds": ("contact",), "certify_estimators": ("gru", "linear")})
    L.run(cfg)
    comp = json.loads((tmp_path / "run" / "comparison.json").read_text())
    assert list(comp["models"]) == ["LeWM (predictor)", "X-JEPA VFX"]
    rep = json.loads((tmp_path / "run" / "compare" / "VFX" / "protocol.json").read_text())
    assert comp["models"]["X-JEPA VFX"]["r2"]["contact"]["log_k"]["ridge"] == rep["probes"]["ridge"]["contact"]["log_k"]
    md = (tmp_path / "run" / "comparison.md").read_text()
    assert "| log_k |" in md and "X-JEPA VFX" in md and "LeWM (predictor)" in md
