"""The certify-your-own-model protocol on planted encoders: an oracle reads the parameters, an input-blind
encoder reads nothing, an action-copying encoder is caught by the leak-free readout, gates mark claims,
and a model or store that breaks the contract raises a pokeworld error."""

import json

import numpy as np
import pytest
import torch
from torch import nn

from pokeworld import certify as C
from pokeworld.data import save
from pokeworld.errors import ConfigError, DataError, ModelError
from pokeworld.evaluate import measure as M
from pokeworld.protocol import certify_model, make_config, run_probes

PARAMS = ("log_m", "gamma", "log_k")
FAST = dict(preset="tiny", kinds=("contact", "all"))  # ridge only, two window kinds: seconds, not minutes


@pytest.fixture(scope="module")
def corpus():
    """160 simulated episodes at 16 px, 64 probe-fit / 64 probe-test: enough for stable held-out R²."""
    from pokeworld.sim.generate import make_config as gen_config, simulate

    cfg = gen_config("tiny", num_episodes=160, batch_envs=160, split_fractions=(0.2, 0.4, 0.4),
                     physics={"image_size": 16})
    return simulate(cfg, progress=False)


def planted_certificates(gamma_oracle: float = 0.7, gamma_drag: float = 0.9) -> dict:
    """Certificates as pokeworld.certify writes them, with the GRU oracle's and drag estimator's γ chosen by the test."""
    est = {"gru": {"contact": {"log_m": 0.8, "gamma": gamma_oracle, "log_k": 0.6}},
           "drag": {"contact": {"gamma": gamma_drag}}}
    cert = C.certificate_table(est, PARAMS)
    return {"estimators": est, "certificate": cert, "gate": C.gate(cert, est), "counts": {}}


def oracle_encoder(ds):
    """States = the episode's true (log m, γ, log k) at every step, found by the step's own observation.

    The lookup is a closure over the dataset: each (proprio, touch) observation identifies its episode,
    so the encoder sees only what the protocol hands it and still knows the answer."""
    table = np.stack([ds.params[p] for p in PARAMS], 1).astype(np.float32)
    keys = np.concatenate([ds.proprio, ds.touch], -1)
    index = {keys[e, t].tobytes(): e for e in range(ds.num_episodes) for t in range(keys.shape[1])}

    def oracle(frames, proprio, touch, actions):
        obs = torch.cat([proprio, touch], -1).numpy()
        ep = np.vectorize(lambda i, j: index[obs[i, j].tobytes()])(*np.indices(obs.shape[:2]))
        return torch.from_numpy(table[ep])

    return oracle


class InputBlind(nn.Module):
    """A 'random encoder': seeded noise states unrelated to any input."""

    def __init__(self, dim: int = 4, seed: int = 0):
        super().__init__()
        self.proj = nn.Linear(1, dim)  # a parameter, so the protocol treats it as a module on its device
        self.gen = torch.Generator().manual_seed(seed)

    def forward(self, frames, proprio, touch, actions):
        return torch.randn(*frames.shape[:2], self.proj.out_features, generator=self.gen)


def leaky(frames, proprio, touch, actions):
    """State at t copies actions[:, t]: whatever it 'knows' came through the action after observation t."""
    return actions.clone()


# --------------------------------------------------------------------------- planted encoders
def test_oracle_reads_the_parameters_and_the_input_blind_encoder_reads_nothing(corpus, tmp_path):
    rep = certify_model(oracle_encoder(corpus), corpus, tmp_path / "oracle", untrained=InputBlind(),
                        certificates=planted_certificates(), name="oracle", **FAST)
    for p in PARAMS:
        assert rep["probes"]["ridge"]["contact"][p] > 0.98 and rep["probes"]["ridge"]["all"][p] > 0.98
        assert -0.3 < rep["untrained"]["ridge"]["contact"][p] < 0.1  # noise states: nothing, up to overfit
        assert rep["claims"][p]["status"] == "claim" and rep["claims"][p]["above_untrained"] > 0.85
    assert rep["model"] == {"name": "oracle", "state_dim": 3}
    assert rep["probes"]["counts"]["contact"]["test"] >= 100
    on_disk = json.loads((tmp_path / "oracle" / "protocol.json").read_text())
    assert on_disk["probes"]["ridge"] == rep["probes"]["ridge"]
    assert (tmp_path / "oracle" / "protocol.png").stat().st_size > 10_000
    md = (tmp_path / "oracle" / "protocol.md").read_text()
    assert "untrained contact" in md and "†" not in md and "no claim" not in md

    blind = certify_model(InputBlind(seed=1), corpus, tmp_path / "blind", certificates=planted_certificates(), **FAST)
    for kind in ("contact", "all"):
        for q, r2 in blind["probes"]["ridge"][kind].items():
            assert -0.3 < r2 < 0.1, (kind, q, r2)


def test_the_mlp_readout_of_the_oracle_reads_its_parameter(corpus, tmp_path):
    # one target: an exact map keeps an MLP improving for all its epochs, and CPU time is the limit here
    rep = certify_model(oracle_encoder(corpus), corpus, tmp_path, certificates=planted_certificates(),
                        **{**FAST, "mlp": True, "kinds": ("contact",), "targets": ("log_k",),
                           "action_conditioned_kinds": ()})
    assert rep["probes"]["mlp"]["contact"]["log_k"] > 0.9
    assert set(rep["probes"]["ridge"]["contact"]) == {"log_k"} and "probes_action_conditioned" not in rep
    assert "| log k | +0.60 |" in (tmp_path / "protocol.md").read_text()  # beside the planted certificate


def test_an_encoder_that_copies_the_action_is_caught_by_the_leak_free_readout(corpus, tmp_path):
    ds = corpus.subset(np.arange(corpus.num_episodes))
    # an action-dependent target, as the scripted policy's object-dependent push makes the real ones
    ds.labels["object_vel"] = M.padded_actions(ds) @ np.array([[1.0, 0.5], [-0.3, 2.0]], np.float32)
    rep = certify_model(leaky, ds, tmp_path, certificates=planted_certificates(),
                        **{**FAST, "action_conditioned_kinds": ("contact", "all")})
    for kind in ("contact", "all"):
        conditioned = rep["probes_action_conditioned"]["ridge"][kind]["object_vel"]
        leak_free = rep["probes"]["ridge"][kind]["object_vel"]
        assert conditioned > 0.95 and -0.1 < leak_free < 0.05, (kind, conditioned, leak_free)
    assert rep["claims"]["object_vel"]["action_conditioned"] > 0.95
    assert "action-conditioned contact" in (tmp_path / "protocol.md").read_text()


class ActionTrunk(nn.Module):
    """measure.py's model interface with the leaky encoder's state: latent ignored, trunk state = action."""

    objective, horizons, tokens = "latent", (), False

    def encode(self, frames, proprio=None, touch=None):
        return torch.as_tensor(np.asarray(proprio)[..., :2]).float()

    def trunk(self, z, actions):
        return torch.as_tensor(np.asarray(actions)).float()


def test_user_models_and_trained_runs_go_through_the_same_probes(corpus):
    cfg = make_config("tiny", kinds=("contact", "glide"))
    mcfg = M.MeasureConfig(kinds=cfg.kinds, max_windows=cfg.max_windows, mlp=False, untrained=False)
    for neutral in (True, False):
        ours = run_probes(leaky, corpus, cfg)["probes" if neutral else "probes_action_conditioned"]
        theirs, _ = M.probe_model(ActionTrunk(), corpus, mcfg, mlp=False, neutral_last_action=neutral,
                                  kinds=cfg.kinds if neutral else cfg.action_conditioned_kinds)
        assert ours == theirs


# --------------------------------------------------------------------------- gate and certificates
def test_a_failed_gate_marks_the_parameter_and_says_no_claim(corpus, tmp_path):
    rep = certify_model(oracle_encoder(corpus), corpus, tmp_path, certificates=planted_certificates(0.27, 0.31),
                        **FAST)
    assert rep["claims"]["gamma"]["status"] == "no claim (gate failed)" and not rep["claims"]["gamma"]["gate_passed"]
    assert rep["claims"]["log_k"]["status"] == "claim" and rep["claims"]["object_pos"]["status"] == "not gated"
    md = (tmp_path / "protocol.md").read_text()
    assert "no claim is made about γ: its gate failed (best estimator drag 0.31 < 0.40; GRU oracle 0.27)" in md
    assert "no claim is made about log k" not in md
    rows = {line.split("|")[1].strip(): line for line in md.splitlines() if line.startswith("| ")}
    assert rows["γ"].count("†") == 3 and "†" not in rows["log k"] and "†" not in rows["obj. position"]
    assert "| γ | drag +0.31 | 0.40 | FAIL | +0.27 (FAIL) |" in md


def test_certificates_are_computed_then_reused_and_a_store_s_own_are_loaded(corpus, tmp_path):
    store = save(corpus.subset(np.arange(60)), tmp_path / "store")  # fewer episodes: the GRU oracle is the cost
    fast = dict(FAST, kinds=("contact",), certify_estimators=("gru", "linear"))
    rep = certify_model(leaky, store, tmp_path / "a", **fast)
    assert rep["certificates"]["source"] == "computed"
    assert set(rep["certificates"]["estimators"]) == {"gru", "linear"}
    assert set(rep["certificates"]["gate"]) == set(PARAMS)
    written = json.loads((tmp_path / "a" / "certificates.json").read_text())
    assert rep["certificates"]["gate"] == C.gate_of(written)
    assert not (store / "certificates.json").exists()  # the user's store is never written

    again = certify_model(leaky, store, tmp_path / "a", **fast)
    assert again["certificates"]["source"] == str(tmp_path / "a" / "certificates.json")
    (store / "certificates.json").write_text(json.dumps(written))
    found = certify_model(leaky, store, tmp_path / "b", **fast)
    assert found["certificates"]["source"] == str(store / "certificates.json")
    assert found["certificates"]["gate"] == rep["certificates"]["gate"]

    other = dict(written, dataset={"content_sha256": "0" * 64})
    with pytest.raises(DataError, match="computed on other data"):
        certify_model(leaky, store, tmp_path / "c", certificates=other, **fast)


# --------------------------------------------------------------------------- contract violations
@pytest.mark.parametrize("bad, match", [
    (lambda f, p, t, a: torch.zeros(f.shape[0], 8), r"shape \(\d+, 8\).*expected \(B=\d+, L=16, D\)"),
    (lambda f, p, t, a: torch.zeros(f.shape[0], f.shape[1] + 1, 8), r"expected \(B=\d+, L=16, D\)"),
    (lambda f, p, t, a: (torch.zeros(*f.shape[:2], 8), None), "returned a tuple"),
    (lambda f, p, t, a: torch.full((*f.shape[:2], 4), float("nan")), r"non-finite state values \(NaN/inf\)"),
])
def test_a_model_that_breaks_the_contract_raises_a_model_error(corpus, tmp_path, bad, match):
    with pytest.raises(ModelError, match=match):
        certify_model(bad, corpus, tmp_path, certificates=planted_certificates(), **FAST)


def test_a_store_without_probe_splits_and_bad_configs_are_refused(corpus, tmp_path):
    ds = corpus.subset(np.arange(corpus.num_episodes))
    ds.split[:] = 0
    with pytest.raises(DataError, match="0 probe-fit and 0 probe-test episodes"):
        certify_model(leaky, ds, tmp_path, **FAST)  # refused before any certificate is computed
    with pytest.raises(ModelError, match="must be callable"):
        certify_model("not a model", corpus, tmp_path, certificates=planted_certificates(), **FAST)
    with pytest.raises(ConfigError, match="unknown window kinds"):
        make_config("tiny", kinds=("sliding",))
    with pytest.raises(ConfigError, match="unknown probe targets"):
        make_config("tiny", targets=("mass",))
    with pytest.raises(ConfigError, match="must include 'gru'"):
        make_config("tiny", certify_estimators=("linear",))
    with pytest.raises(DataError, match="does not exist"):
        certify_model(leaky, tmp_path / "missing", tmp_path)
