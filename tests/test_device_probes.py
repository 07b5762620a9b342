"""Measurement and planning on the model's device: the torch estimators, the device probe path of a measurement and
the planner's device decoder agree with the numpy / sklearn path, checked on the CPU (where both can run)."""

import numpy as np
import pytest
import torch

from pokeworld import plan, train
from pokeworld.data import save
from pokeworld.errors import ConfigError
from pokeworld.evaluate import measure as M
from pokeworld.evaluate import probes
from pokeworld.evaluate.state import EpisodeLatents, padded_actions, probes_on_device, window_states
from pokeworld.regressors import ALPHAS, RidgeCV, TorchRegressor, r2_scores, ridge_path
from pokeworld.windows import make_windows


def both_paths(X, Y, groups, fit, test):
    """The numpy / sklearn fit and the torch one (CPU tensors) of the same data: (numpy fit, torch fit, numpy
    predictions, torch predictions) on the test rows."""
    a = RidgeCV().fit(X[fit], Y[fit], groups[fit])
    b = RidgeCV().fit(torch.as_tensor(X[fit]), Y[fit], groups[fit])
    pb = b.predict(torch.as_tensor(X[test]))
    assert isinstance(pb, torch.Tensor)
    return a, b, a.predict(X[test]), pb.numpy()


def planted(rng, n=600, d=12, noise=0.1):
    X = rng.normal(size=(n, d))
    W = rng.normal(size=(d, 2))
    return X, X @ W + noise * rng.normal(size=(n, 2)), np.repeat(np.arange(n // 10), 10)


def collinear(rng, n=300, d=80):
    """Features that are noisy copies of 4 factors (rank ~4, condition number ~1e12), the target one of them."""
    F = rng.normal(size=(n, 4))
    X = F @ rng.normal(size=(4, d)) + 1e-6 * rng.normal(size=(n, d))
    return X, F[:, :1] * 2.0 + 0.05 * rng.normal(size=(n, 1)), np.repeat(np.arange(n // 6), 6)


def assert_same_fit(a, b, pa, pb):
    assert a.alpha == b.alpha
    assert abs(a.cv_r2 - b.cv_r2) <= 1e-6
    np.testing.assert_allclose(pb, pa, rtol=0, atol=1e-6)


def test_torch_ridge_equals_the_numpy_ridge_on_a_planted_linear_problem(rng):
    X, Y, g = planted(rng)
    fit, test = np.arange(len(X)) < 450, np.arange(len(X)) >= 450
    a, b, pa, pb = both_paths(X, Y, g, fit, test)
    assert_same_fit(a, b, pa, pb)
    assert r2_scores(Y[test], pa).mean() > 0.9 and r2_scores(Y[test], pb).mean() > 0.9
    # pure noise: nothing to recover on held-out episodes on either path
    noise = rng.normal(size=Y.shape)
    a, b, pa, pb = both_paths(X, noise, g, fit, test)
    assert_same_fit(a, b, pa, pb)
    assert r2_scores(noise[test], pa).mean() < 0.05 and r2_scores(noise[test], pb).mean() < 0.05


@pytest.mark.parametrize("n_fit", [60, 240])  # fewer rows than features (dual path) and more (primal)
def test_torch_ridge_equals_the_numpy_ridge_on_a_collinear_problem(rng, n_fit):
    X, y, g = collinear(rng)
    fit, test = np.arange(len(X)) < n_fit, np.arange(len(X)) >= 240
    a, b, pa, pb = both_paths(X, y, g, fit, test)
    assert_same_fit(a, b, pa, pb)
    assert r2_scores(y[test], pb)[0] > 0.9


@pytest.mark.parametrize("d", [8, 200])
def test_torch_ridge_path_equals_the_numpy_one_for_every_alpha(rng, d):
    X, Y, X_eval = rng.normal(size=(100, d)), rng.normal(size=(100, 3)), rng.normal(size=(20, d))
    want = ridge_path(X, Y, X_eval, ALPHAS)
    got = ridge_path(torch.as_tensor(X), torch.as_tensor(Y), torch.as_tensor(X_eval), ALPHAS)
    for w, g in zip(want, got):
        assert isinstance(g, torch.Tensor) and g.dtype == torch.float64
        np.testing.assert_allclose(g.numpy(), w, rtol=1e-8, atol=1e-8)


def test_the_affine_form_of_a_ridge_predicts_what_it_predicts(rng):
    X, Y, g = planted(rng)
    for x in (X.astype(np.float32), X):  # float32 inputs are how states and latents are decoded
        a = RidgeCV().fit(x, Y, g)
        W, b = a.affine()
        np.testing.assert_allclose(x.astype(float) @ W + b, a.predict(x), atol=1e-5)
    t = RidgeCV().fit(torch.as_tensor(X), Y[:, 0], g)  # a 1-d target: one output column
    W, b = t.affine()
    assert W.shape == (X.shape[1], 1) and b.shape == (1,)
    np.testing.assert_allclose((torch.as_tensor(X) @ W + b).numpy(), t.predict(torch.as_tensor(X)).numpy(),
                               atol=1e-10)


def test_the_mlp_probe_trains_on_its_inputs_device_like_on_arrays(rng):
    X = rng.normal(size=(400, 10)).astype(np.float32)
    y = np.tanh(X[:, :2]).sum(1, keepdims=True) + 0.1 * rng.normal(size=(400, 1))
    g = np.repeat(np.arange(40), 10)
    kw = dict(hidden=32, epochs=15, patience=5, seed=3)
    a = TorchRegressor("mlp", **kw).fit(X[:300], y[:300], g[:300])
    b = TorchRegressor("mlp", **kw).fit(torch.as_tensor(X[:300]), y[:300], g[:300])
    pb = b.predict(torch.as_tensor(X[300:]))
    assert isinstance(pb, torch.Tensor)
    # the same split, batch order and initial weights: the same net but for float rounding of the standardiser
    np.testing.assert_allclose(pb.numpy(), a.predict(X[300:]), atol=1e-4)


# --------------------------------------------------------------------------- a tiny trained run
@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory, tiny_dataset):
    d = tmp_path_factory.mktemp("device")
    save(tiny_dataset, d / "data")
    run = train.run(train.make_config("tiny", data=str(d / "data"), out=str(d / "VFX"), variant="VFX"))
    return run, tiny_dataset


def test_which_path_a_measurement_probes_on():
    cpu_model = torch.nn.Linear(2, 2)
    assert not probes_on_device("auto", cpu_model) and not probes_on_device("host", cpu_model)
    assert probes_on_device("model", cpu_model)
    with pytest.raises(ConfigError, match="probe_device must be one of"):
        M.MeasureConfig(probe_device="gpu")


def test_device_probes_equal_the_numpy_probes_on_a_trained_run(tiny_run, monkeypatch):
    """Forcing the device path (torch on the CPU) reproduces every ridge R² of a measurement. The default path
    standardises float32 states in float32 and sklearn refits in float32, the device path does all in float64, so
    the two differ by that float32 rounding (4.5e-5 at most here, on states of condition number ~6e6); given the
    same states in float64 the two paths are one estimator (the next test, to 1e-6)."""
    run, ds = tiny_run
    model = train.load_model(run, map_location="cpu")
    seen = []

    class Recording(RidgeCV):  # which path every probe fit took
        def fit(self, X, Y, groups):
            seen.append(type(X))
            return super().fit(X, Y, groups)

    monkeypatch.setattr(probes, "RidgeCV", Recording)
    bound = M.untrained_copy(model)
    host = M.measure(model, ds, M.make_config("tiny", probe_device="host"), bound)
    assert seen and set(seen) == {np.ndarray}
    seen.clear()
    dev = M.measure(model, ds, M.make_config("tiny", probe_device="model"), bound)
    assert seen and set(seen) == {torch.Tensor}
    n = 0
    for readout in ("probes", "probes_action_conditioned", "untrained"):
        for kind, per in host[readout]["ridge"].items():
            assert set(dev[readout]["ridge"][kind]) == set(per)
            for target, r2 in per.items():
                assert dev[readout]["ridge"][kind][target] == pytest.approx(r2, abs=2e-4), (readout, kind, target)
                n += 1
        assert dev[readout]["counts"] == host[readout]["counts"]
    assert n >= 20
    assert dev["prediction"] == host["prediction"]  # decoded on the host either way, from the same latents


def test_device_probes_are_the_numpy_estimator_on_a_trained_runs_states(tiny_run):
    """The probe loop on the trained run's states: the device path (float32 tensors, probed in float64 torch) and
    the numpy / sklearn path given the same states in float64 agree to 1e-6 on every target and window kind."""
    run, ds = tiny_run
    model = train.load_model(run, map_location="cpu")
    cfg = M.make_config("tiny")
    lat = dict(zip(("fit", "test"), probes.probe_latents(model, ds, cfg, on_device=True)))
    acts = padded_actions(ds)

    def states(w, part):
        return window_states(model, ds, lat[part], w, acts, on_device=True)

    args = (cfg.kinds, cfg.window, cfg.stride, cfg.max_windows, cfg.seed, False)
    dev = probes.probe_windows(ds, states, *args)
    host = probes.probe_windows(ds, lambda w, part: states(w, part).numpy().astype(np.float64), *args)
    assert dev["counts"] == host["counts"] and set(dev["ridge"]) == set(host["ridge"]) and len(host["ridge"]) >= 2
    for kind, per in host["ridge"].items():
        assert len(per) >= 7
        for target, r2 in per.items():
            assert dev["ridge"][kind][target] == pytest.approx(r2, abs=1e-6), (kind, target)


def test_device_states_are_the_host_states(tiny_run):
    run, ds = tiny_run
    model = train.load_model(run, map_location="cpu")
    eps = ds.episodes("probe_fit")[:8]
    w, acts = make_windows(ds, eps, 16, 4), padded_actions(ds)
    want = window_states(model, ds, EpisodeLatents(model, ds, eps, 4), w, acts)
    got = window_states(model, ds, EpisodeLatents(model, ds, eps, 4, on_device=True), w, acts, on_device=True)
    assert isinstance(got, torch.Tensor) and got.device == torch.device("cpu")
    np.testing.assert_array_equal(got.numpy(), want)


# --------------------------------------------------------------------------- planning
def start_history(cfg, setup):
    sim, obs = plan.start_sim(cfg, setup)
    return {"frames": obs["vision"][:, None, ..., 0], "proprio": obs["proprio"][:, None], "touch": obs["touch"][:, None],
            "actions": np.zeros((cfg.episodes, 0, 2), np.float32)}


def test_the_device_decoder_decodes_and_costs_like_the_numpy_one(tiny_run):
    run, _ = tiny_run
    cfg = plan.make_config("tiny", population=16)
    setup = plan.episode_setup(cfg)
    hist, cand, goal = start_history(cfg, setup), plan.rank_candidates(cfg), setup["goal"]
    scorer = plan.LatentScorer(str(run), "")
    assert not scorer.on_device  # a CPU model keeps the numpy decoder path
    want, got = scorer.positions(hist, cand), scorer.device_positions(hist, cand)
    for d, _ in plan.COST_TERMS:
        assert isinstance(got[d], torch.Tensor) and got[d].shape == want[d].shape == (cfg.episodes, 16, 2)
        # the numpy decoder predicts in float32 (it was fit on float32 latents): its rounding, relative to the
        # position (a 10-step model decodes its predictions far outside the unit arena)
        np.testing.assert_allclose(got[d].numpy(), want[d], rtol=1e-6, atol=1e-5)
    assert np.ptp(want[16]) > 1e-3  # the candidates decode to different positions: the check has teeth
    np.testing.assert_allclose(scorer.device_score(hist, cand, goal), scorer.score(hist, cand, goal), rtol=1e-6)


def test_planning_with_the_device_decoder_plans_what_the_numpy_decoder_plans(tiny_run):
    run, _ = tiny_run
    cfg = plan.make_config("tiny")
    setup = plan.episode_setup(cfg)
    numpy_path = plan.LatentScorer(str(run), "")

    class DeviceScored(plan.LatentScorer):
        def score(self, hist, cand, goal):
            return self.device_score(hist, cand, goal)

    want = plan.control(cfg, setup, numpy_path)
    got = plan.control(cfg, setup, DeviceScored(str(run), ""))
    np.testing.assert_array_equal(got["object_path"], want["object_path"])
    np.testing.assert_array_equal(got["finger_path"], want["finger_path"])


# --------------------------------------------------------------------------- on a GPU (skipped without one)
needs_cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")


@needs_cuda
def test_a_gpu_measurement_probes_on_the_gpu_and_reads_the_cpus_numbers(tiny_run, monkeypatch):
    """probe_device 'auto' on a CUDA model: every probe fit gets states on the GPU, and the R² numbers equal the
    CPU measurement's but for float rounding of the GPU states (fp32, TF32 off)."""
    run, ds = tiny_run
    cpu, gpu = (train.load_model(run, map_location=d) for d in ("cpu", "cuda"))
    seen = []

    class Recording(RidgeCV):
        def fit(self, X, Y, groups):
            seen.append(X.device.type if isinstance(X, torch.Tensor) else "host")
            return super().fit(X, Y, groups)

    monkeypatch.setattr(probes, "RidgeCV", Recording)
    want = M.measure(cpu, ds, M.make_config("tiny"), M.untrained_copy(cpu))
    assert set(seen) == {"host"}
    seen.clear()
    with M.full_precision(torch.device("cuda")):
        got = M.measure(gpu, ds, M.make_config("tiny"), M.untrained_copy(gpu))
    assert seen and set(seen) == {"cuda"}
    for readout in ("probes", "probes_action_conditioned", "untrained"):
        for kind, per in want[readout]["ridge"].items():
            for target, r2 in per.items():
                assert got[readout]["ridge"][kind][target] == pytest.approx(r2, abs=2e-3), (readout, kind, target)


@needs_cuda
def test_a_gpu_planner_scores_on_the_gpu_like_the_cpu(tiny_run):
    run, _ = tiny_run
    cfg = plan.make_config("tiny", population=16)
    setup = plan.episode_setup(cfg)
    hist, cand, goal = start_history(cfg, setup), plan.rank_candidates(cfg), setup["goal"]
    cpu, gpu = plan.LatentScorer(str(run), ""), plan.LatentScorer(str(run), "", device="cuda")
    assert gpu.on_device and gpu.decoder_affine[0].device.type == "cuda"
    with M.full_precision(torch.device("cuda")):
        got = gpu.score(hist, cand, goal)
    assert isinstance(got, np.ndarray) and got.shape == (cfg.episodes, 16)
    np.testing.assert_allclose(got, cpu.score(hist, cand, goal), rtol=1e-3)
