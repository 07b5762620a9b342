"""The training paths on a CUDA device (skipped without one; run on a GPU machine with ``pytest tests/test_cuda.py``).

CI has no GPU, so these are the checks that the CPU suite cannot make: the fast path (pinned non-blocking
uploads, fused AdamW, bf16 autocast) trains, resumes and is read back on the CPU; stacked members on the GPU
equal their separate GPU runs; the compiled loss trains; the default on CUDA (CUDA graphs, ``compile`` 'auto'),
single and stacked, trains like the eager path and resumes from its checkpoint like an uninterrupted run; a
GPU-trained run is measured. The tolerances allow for bf16 autocast and non-deterministic cuDNN kernels, not for a
wrong batch or a wrong update.
"""

import copy
import json
import os
import time

import numpy as np
import pytest
import torch

from pokeworld import train
from pokeworld.train import stacked as train_stacked
from pokeworld.data import save

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")

# 32 px keeps the CNN alive (at tiny's 16 px its GroupNorm zeroes the CNN gradient); dropout 0 so that
# stacked and separate runs, and resumed and uninterrupted ones, see the same masks (none). The fast-path
# tests train eagerly (compile 'off'); the CUDA-graph default has its own tests below
BASE = dict(image_size=32, dropout=0.0, device="cuda", steps=8, log_every=2, ckpt_every=2, compile="off")
DEFAULT = {k: v for k, v in BASE.items() if k != "compile"}  # compile 'auto': CUDA graphs on this device


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    ds = train.synthetic_dataset(num_episodes=12, steps=24, size=32, seed=0)
    ds.touch[..., :6] += np.random.default_rng(1).normal(0, 0.1, ds.touch[..., :6].shape).astype(np.float32)
    d = tmp_path_factory.mktemp("cuda") / "syn"
    save(ds, d)
    return str(d)


# The order and the budget (docs/model.md "GPU allocations"): the tests on the paper map's path come first (the CUDA-
# graph default trains and resumes; a GPU-trained run is measured; GPU states equal the CPU's), then the fast path,
# then compilation and stacking, whose compilations cost most. POKEWORLD_CUDA_BUDGET_S (unset: no budget) skips every
# test that would start past the budget: elapsed since the first test here + its expected seconds (the duration
# recorded in POKEWORLD_CUDA_TIMES when that file holds one, else PRIOR_S: guesses until a GPU measures them), and
# each skip names itself (pytest -rs), so a device log says exactly which tests did not run.
PRIOR_S = {"test_the_cuda_default_trains_as_eager_and_resumes": 45, "test_a_gpu_trained_run_is_measured": 10,
           "test_gpu_states_equal_cpu_states": 5, "test_fast_path_trains_resumes_and_loads_on_the_cpu": 8,
           "test_fast_path_equals_the_plain_path_on_cuda": 6, "test_compiled_loss_trains_on_cuda": 25,
           "test_stacked_members_equal_their_separate_runs_on_cuda": 10,
           "test_the_cuda_default_trains_stacked_groups_as_eager_and_resumes": 45}
_clock: dict = {}


def _recorded() -> dict:
    path = os.environ.get("POKEWORLD_CUDA_TIMES")
    if not (path and os.path.exists(path)):
        return {}
    with open(path) as f:
        times = json.load(f)
    return times if isinstance(times, dict) else {}


def _expected_s(name: str, function: str) -> float:
    """Seconds test ``name`` (one parametrisation of ``function``) is expected to take."""
    measured = _recorded().get(name)
    return float(measured) if isinstance(measured, (int, float)) else float(PRIOR_S.get(function, 30))


@pytest.fixture(autouse=True)
def within_budget(request):
    """Skip a test that would start past POKEWORLD_CUDA_BUDGET_S; record each duration in POKEWORLD_CUDA_TIMES."""
    name, function = request.node.name, request.node.originalname
    start = _clock.setdefault("start", time.monotonic())
    budget = os.environ.get("POKEWORLD_CUDA_BUDGET_S")
    elapsed = time.monotonic() - start
    expected = _expected_s(name, function)
    if budget and elapsed + expected > float(budget):
        pytest.skip(f"CUDA budget: {elapsed:.0f} s of {float(budget):.0f} spent and {name} expects "
                    f"{expected:.0f} s: not run")
    t0 = time.monotonic()
    yield
    path = os.environ.get("POKEWORLD_CUDA_TIMES")
    if path:
        times = {**_recorded(), name: round(time.monotonic() - t0, 1)}
        with open(path, "w") as f:
            json.dump(times, f, indent=1, sort_keys=True)


def _rows(d):
    return [json.loads(x) for x in (d / "metrics.jsonl").read_text().splitlines()]


def _close_runs(a, b, rel):
    ra, rb = _rows(a), _rows(b)
    assert [r["step"] for r in ra] == [r["step"] for r in rb]
    for x, y in zip(ra[1:], rb[1:]):
        assert np.isfinite(x["loss"]) and y["loss"] == pytest.approx(x["loss"], rel=rel)


@pytest.fixture
def compile_modes(monkeypatch):
    """The modes torch.compile is called with (it still compiles)."""
    real, seen = torch.compile, []

    def spy(fn, *a, mode=None, **kw):
        seen.append(mode)
        return real(fn, *a, mode=mode, **kw)

    monkeypatch.setattr(torch, "compile", spy)
    return seen


#: the objective and model the paper preset trains (train.config.REFERENCE_MODEL) at tiny sizes: its BatchNorm-ended
#: heads and frame-mean contact weighting under CUDA graphs are what an allocation's map runs (first in each pair)
REFERENCE_FORM = dict(encoder="reference", head_form="reference", sensor_horizons=(1, 4),
                      latent_horizon_weights=(1.0, 0.5), sensor_horizon_weights=(0.5, 0.25),
                      contact_weighting="frames", sigreg_pool="pooled", sigreg_knots=9, sigreg_t_max=5.0, grad_clip=5.0)
FORMS = pytest.mark.parametrize("form", [REFERENCE_FORM, {}], ids=["reference", "first"])


@FORMS
def test_the_cuda_default_trains_as_eager_and_resumes(data_dir, tmp_path, compile_modes, form):
    kw = dict(data=data_dir, variant="VFX", **DEFAULT, **form)
    cfg = train.make_config("tiny", out=str(tmp_path / "graphs"), **kw)
    assert train.compile_mode_for(cfg, torch.device("cuda")) == "reduce-overhead"
    graphs = train.run(cfg)
    assert compile_modes == ["reduce-overhead"]
    eager = train.run(train.make_config("tiny", out=str(tmp_path / "eager"), **{**kw, "compile": "off"}))
    _close_runs(eager, graphs, rel=2e-2)
    train.run(train.make_config("tiny", out=str(tmp_path / "resumed"), stop_at=4, **kw))  # checkpoint at step 4
    assert not (tmp_path / "resumed" / "DONE").exists()
    resumed = train.run(train.make_config("tiny", out=str(tmp_path / "resumed"), **kw))
    _close_runs(graphs, resumed, rel=2e-2)
    assert json.loads((resumed / "config.json").read_text())["compile"] == "auto"


def test_a_gpu_trained_run_is_measured(data_dir, tmp_path, tiny_dataset):
    from pokeworld.evaluate import measure

    d = tmp_path / "sim"
    save(tiny_dataset, d)
    kw = {**BASE, "image_size": 16}  # the tiny corpus's frames
    run_dir = train.run(train.make_config("tiny", data=str(d), out=str(tmp_path / "m"), variant="VFX", **kw))
    res = json.loads(measure.run(measure.make_config("tiny", run_dir=str(run_dir))).read_text())
    assert "ridge" in res["probes"] and np.isfinite(res["prediction"]["direct16"])


def test_gpu_states_equal_cpu_states(tiny_dataset):
    """The probed states read on the GPU (fp32, TF32 off) equal the CPU's to float rounding, which is why a
    measurement's key omits the device."""
    from pokeworld.evaluate.measure import full_precision
    from pokeworld.evaluate.state import EpisodeLatents, padded_actions, window_states
    from pokeworld.models import XJEPA
    from pokeworld.windows import make_windows

    ds = tiny_dataset
    torch.manual_seed(0)
    cpu = XJEPA(variant="VFX", proprio_dim=ds.proprio.shape[-1], touch_dim=ds.touch.shape[-1],
                action_dim=ds.actions.shape[-1], image_size=32, channels=(8, 16, 16, 16), latent_dim=16, width=32,
                depth=1, heads=2, vec_dim=8).eval()
    gpu = copy.deepcopy(cpu).to("cuda")
    eps = ds.episodes("probe_test")[:8]
    w, acts = make_windows(ds, eps, 16, 4), padded_actions(ds)
    want = window_states(cpu, ds, EpisodeLatents(cpu, ds, eps, 8), w, acts)
    with full_precision(torch.device("cuda")):
        got = window_states(gpu, ds, EpisodeLatents(gpu, ds, eps, 8), w, acts)
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5 * np.abs(want).max())


def test_fast_path_trains_resumes_and_loads_on_the_cpu(data_dir, tmp_path):
    kw = dict(data=data_dir, variant="VFX", **BASE)
    a = train.run(train.make_config("tiny", out=str(tmp_path / "a"), **kw))
    cfg = train.make_config("tiny", out=str(tmp_path / "b"), stop_at=4, **kw)
    assert train.use_fast_path(cfg, torch.device("cuda"))
    train.run(cfg)
    assert not (tmp_path / "b" / "DONE").exists()
    b = train.run(train.make_config("tiny", out=str(tmp_path / "b"), **kw))
    _close_runs(a, b, rel=2e-2)
    rows = _rows(a)
    assert rows[-1]["loss"] < rows[1]["loss"]
    model = train.load_model(a, map_location="cpu")  # a GPU checkpoint is read on a machine without one
    assert next(model.parameters()).device.type == "cpu"


def test_fast_path_equals_the_plain_path_on_cuda(data_dir, tmp_path):
    kw = dict(data=data_dir, variant="VX_t", **BASE)
    plain = train.run(train.make_config("tiny", out=str(tmp_path / "plain"), fast="off", **kw))
    fast = train.run(train.make_config("tiny", out=str(tmp_path / "fast"), fast="on", **kw))
    _close_runs(plain, fast, rel=2e-2)


def test_compiled_loss_trains_on_cuda(data_dir, tmp_path):
    kw = {**BASE, "compile": "on", "compile_mode": "default"}  # torch.compile's default mode (no CUDA graphs)
    out = train.run(train.make_config("tiny", data=data_dir, out=str(tmp_path / "c"), variant="VFX", **kw))
    rows = _rows(out)
    assert (out / "DONE").exists() and all(np.isfinite(r["loss"]) for r in rows[1:])


def test_stacked_members_equal_their_separate_runs_on_cuda(data_dir, tmp_path):
    members = [dict(variant="VFX", seed=0, sigreg_weight=0.02), dict(variant="V", seed=1)]
    sep = [train.run(train.make_config("tiny", data=data_dir, out=str(tmp_path / f"s{i}"), **BASE, **m))
           for i, m in enumerate(members)]
    cfgs = [train.make_config("tiny", data=data_dir, out=str(tmp_path / f"k{i}"), **BASE, **m)
            for i, m in enumerate(members)]
    stk = train_stacked.run(cfgs)
    for s, k in zip(sep, stk):
        assert (k / "DONE").exists()
        _close_runs(s, k, rel=2e-2)


@FORMS
def test_the_cuda_default_trains_stacked_groups_as_eager_and_resumes(data_dir, tmp_path, compile_modes, form):
    members = [dict(variant="VFX", seed=0), dict(variant="V", seed=1)]

    def cfgs(name, **extra):
        return [train.make_config("tiny", data=data_dir, out=str(tmp_path / f"{name}{i}"), **DEFAULT, **m, **form,
                                  **extra)
                for i, m in enumerate(members)]

    graphs = train_stacked.run(cfgs("g"))
    assert compile_modes == ["reduce-overhead"]
    eager = train_stacked.run(cfgs("e", compile="off"))
    train_stacked.run(cfgs("r", stop_at=4))
    resumed = train_stacked.run(cfgs("r"))
    for g, e, r in zip(graphs, eager, resumed):
        assert (g / "DONE").exists() and (r / "DONE").exists()
        _close_runs(e, g, rel=2e-2)
        _close_runs(g, r, rel=2e-2)
