"""The certify-your-own-model protocol on planted encoders: an oracle reads the parameters, an input-blind
encoder reads nothing, an action-copying encoder is caught by the leak-free readout, gates mark claims,
and a model or store that breaks the contract raises a pokeworld error."""

import json
import re

import numpy as np
import pytest
import torch
from torch import nn

from pokeworld import certify as C
from pokeworld.data import save
from pokeworld.errors import ConfigError, DataError, ModelError
from pokeworld.evaluate import measure as M
from pokeworld.protocol import MAX_STATE, StateReader, certify_model, make_config, run_probes
from pokeworld.windows import make_windows

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
def noisy(scale: float, dtype=np.float64):
    """A numpy model whose states are seeded noise of magnitude ``scale``: finite, and as large as asked."""
    rng = np.random.default_rng(0)
    return lambda f, p, t, a: (rng.standard_normal((*f.shape[:2], 4)) * scale).astype(dtype)


@pytest.mark.parametrize("bad, match", [
    # shape: the batch, the window length and the state width must be those the protocol asked for
    (lambda f, p, t, a: torch.zeros(f.shape[0], 8), r"shape \(\d+, 8\).*expected \(B=\d+, L=16, D\)"),
    (lambda f, p, t, a: torch.zeros(f.shape[0], f.shape[1] + 1, 8), r"\(\d+, 17, 8\).*expected \(B=\d+, L=16, D\)"),
    (lambda f, p, t, a: torch.zeros(f.shape[0], f.shape[1] - 1, 8), r"\(\d+, 15, 8\).*expected \(B=\d+, L=16, D\)"),
    (lambda f, p, t, a: torch.zeros(1, *f.shape[1:2], 8), r"shape \(1, 16, 8\) for \d+ windows.*expected \(B="),
    (lambda f, p, t, a: torch.zeros(f.shape[0] - 1, *f.shape[1:2], 8), r"for (\d+) windows.*expected \(B=\1, L=16"),
    (lambda f, p, t, a: torch.zeros(*f.shape[:2], 0), r"shape \(\d+, 16, 0\)"),
    # one state a batch: the width follows the batch size (256 windows, then the rest)
    (lambda f, p, t, a: torch.zeros(*f.shape[:2], f.shape[0]), r"state width \d+ after 256 earlier"),
    (lambda f, p, t, a: (torch.zeros(*f.shape[:2], 8), None), "returned a tuple"),
    # not plain real numbers: numpy would convert all of these with at most a warning
    (lambda f, p, t, a: None, "returned None"),
    (lambda f, p, t, a: np.full((*f.shape[:2], 4), "1.5"), r"returned ndarray of dtype <U3, not numbers"),
    (lambda f, p, t, a: np.ones((*f.shape[:2], 4), dtype=object), r"dtype object, not numbers"),
    (lambda f, p, t, a: "states", r"returned str of dtype <U6, not numbers"),
    (lambda f, p, t, a: torch.ones(*f.shape[:2], 4, dtype=torch.complex64), r"complex states \(torch.complex64\)"),
    (lambda f, p, t, a: np.ones((*f.shape[:2], 4), dtype=np.complex128), r"complex states \(complex128\)"),
    # values
    (lambda f, p, t, a: torch.full((*f.shape[:2], 4), float("nan")), r"non-finite state values \(NaN/inf\)"),
    (lambda f, p, t, a: torch.full((*f.shape[:2], 4), float("-inf")), r"non-finite state values \(NaN/inf\)"),
    (noisy(1e20, np.float32), r"as large as [\d.]+e\+2\d .*exceed \|x\| <= 1e\+15.*standardisation can overflow"),
    (noisy(1e30), r"as large as [\d.]+e\+3\d .*exceed \|x\| <= 1e\+15.*standardisation can overflow"),
    (noisy(1e39), r"as large as [\d.]+e\+39 .*overflow to inf when the protocol reads states as float32"),
])
def test_a_model_that_breaks_the_contract_raises_a_model_error(corpus, tmp_path, bad, match):
    with pytest.raises(ModelError, match=match):
        certify_model(bad, corpus, tmp_path, certificates=planted_certificates(), **FAST)


def test_real_valued_states_of_any_numeric_dtype_within_the_bound_are_read_as_float32(corpus):
    # six episodes: enough windows that some last frame has the object or finger in the corner the bound reads
    w = make_windows(corpus, corpus.episodes("probe_fit")[:6], 16, 4)
    cfg = make_config("tiny", batch_windows=7, inputs="numpy")  # several batches, the last one short
    assert len(w) > cfg.batch_windows and len(w) % cfg.batch_windows
    at_bound = lambda f: np.where(f[..., :2, 0] > 100, -MAX_STATE, f[..., :2, 0])  # noqa: E731  (allowed)
    assert (at_bound(w.gather(corpus.frames)[:, -1]) == -MAX_STATE).any()
    for states, expect in [
        (lambda f, p, t, a: f[..., :2, 0] > 100, lambda f: (f[..., :2, 0] > 100).astype(np.float32)),
        (lambda f, p, t, a: f[..., :3, 0].astype(np.int64) - 2**40, lambda f: f[..., :3, 0] - np.float32(2**40)),
        (lambda f, p, t, a: at_bound(f), lambda f: at_bound(f).astype(np.float32)),
        (lambda f, p, t, a: torch.as_tensor(f[..., :2, 0], dtype=torch.float16),
         lambda f: f[..., :2, 0].astype(np.float32)),
    ]:
        out = StateReader(states, corpus, cfg)(w)
        assert out.dtype == np.float32 and out.shape[0] == len(w)
        assert np.array_equal(out, expect(w.gather(corpus.frames)[:, -1]))


class Raising(nn.Module):
    """A module that raises ``error`` on its ``at``-th call and records the inputs of that call."""

    def __init__(self, error: BaseException, at: int = 2):
        super().__init__()
        self.proj = nn.Linear(1, 4)
        self.error, self.at, self.calls, self.seen = error, at, 0, None

    def forward(self, frames, proprio, touch, actions):
        self.calls += 1
        if self.calls == self.at:
            self.seen = (frames.numpy().copy(), proprio.numpy().copy())
            raise self.error
        return torch.randn(*frames.shape[:2], 4)


def test_a_model_that_raises_is_reported_with_the_window_it_failed_on_and_left_in_training_mode(corpus, tmp_path):
    model = Raising(RuntimeError("shape mismatch in layer 3")).train()
    with pytest.raises(ModelError) as info:
        certify_model(model, corpus, tmp_path, certificates=planted_certificates(), **FAST, batch_windows=100)
    msg = str(info.value)
    assert msg.startswith("the model raised RuntimeError: shape mismatch in layer 3 on windows 100..199 of ")
    assert isinstance(info.value.__cause__, RuntimeError) and info.value.__cause__ is model.error
    assert model.training  # eval() for the readout is undone on the way out
    # the named window is the batch's first: its frames and proprioception are the store's at those steps
    ep, first, last = map(int, re.search(r"first window: episode (\d+), steps (\d+)\.\.(\d+)\)", msg).groups())
    assert last - first == 15 and corpus.split[ep] == 1  # a probe-fit episode
    frames, proprio = model.seen
    assert np.array_equal(frames[0], corpus.frames[ep, first:last + 1])
    assert np.array_equal(proprio[0], corpus.proprio[ep, first:last + 1].astype(np.float32))
    lo, hi = map(int, re.search(r"episodes (\d+)\.\.(\d+);", msg).groups())
    assert lo <= ep <= hi

    oom = Raising(MemoryError("out of memory"), at=1)
    oom_match = r"raised MemoryError: out of memory on windows 0\.\.99 .*lower batch_windows \(now 100\)"
    with pytest.raises(ModelError, match=oom_match):
        certify_model(oom, corpus, tmp_path, certificates=planted_certificates(), **FAST, batch_windows=100)


@pytest.mark.parametrize("error", [KeyboardInterrupt(), SystemExit(3)])
def test_an_interrupt_inside_the_model_is_not_turned_into_a_model_error(corpus, tmp_path, error):
    model = Raising(error, at=1).train()
    with pytest.raises(type(error)) as info:
        certify_model(model, corpus, tmp_path, certificates=planted_certificates(), **FAST)
    assert info.value is error and model.training


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
