"""The paper preset's objective and model against the authors' released reference (issue 59): parameter counts per
variant, SIGReg's definition, the loss weights and the head and encoder forms. No training."""

import math

import pytest
import torch

from pokeworld.errors import ConfigError
from pokeworld.losses import sigreg
from pokeworld.models import VARIANTS, XJEPA
from pokeworld.models.xjepa import ReferenceDeltaHead, combine_horizons
from pokeworld.published import release as R
from pokeworld.train import loss_kwargs, model_kwargs, sigreg_row_index
from pokeworld.train.config import FIRST_PAPER_MODEL, make_config

DIMS = (4, 7, 2)


def n_params(model: torch.nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_paper_preset_parameter_count_is_within_two_percent_of_the_reference(variant):
    with torch.device("meta"):  # shapes only: no memory, no initialisation cost
        ours = n_params(XJEPA(**model_kwargs(make_config("paper", variant=variant), DIMS)))
        first = n_params(XJEPA(**model_kwargs(make_config("paper", variant=variant, **FIRST_PAPER_MODEL), DIMS)))
    ref = R.RUNS[variant]["params"]
    assert abs(ours / ref - 1) <= 0.02, (variant, ours, ref)
    # the count can come out either way: the first model misses the target on every variant with a touch or proprio
    # head (its Δ16 sensor heads and 192-wide hidden layers), so the check is not vacuous
    if VARIANTS[variant][1] != ("latent",):
        assert abs(first / ref - 1) > 0.02, (variant, first, ref)


def reference_sigreg(z: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
    """The released reference's statistic, written from its definition: the complex ECF of the projections on a
    17-knot grid over [−5, 5], |ECF − e^{−t²/2}|² weighted by e^{−t²/2}, trapezoid, times N, mean over directions."""
    t = torch.linspace(-5, 5, 17, dtype=torch.float64)
    target = torch.exp(-0.5 * t**2)
    proj = (z.double() @ directions.double()).unsqueeze(-1) * t  # (N, K, knots)
    ecf = torch.exp(1j * proj).mean(0)
    err = (ecf - target).abs().square() * target
    return (torch.trapezoid(err, t, dim=-1) * z.shape[0]).mean()


def test_paper_sigreg_is_the_reference_statistic_over_every_row_of_the_batch():
    cfg = make_config("paper")
    gen = torch.Generator().manual_seed(0)
    z = torch.randn(cfg.batch_size, cfg.window, 16, generator=gen) * 1.3 + 0.2  # off the null, so the value matters
    dirs = torch.randn(16, 64, generator=gen)
    dirs = dirs / dirs.norm(dim=0, keepdim=True)
    # pooled over all B×T = 3,072 rows, none subsampled
    assert sigreg_row_index(cfg, 7, torch.device("cpu")) is None
    rows = z.reshape(-1, 16)
    ours = sigreg(rows, directions=dirs, num_knots=cfg.sigreg_knots, t_max=cfg.sigreg_t_max)
    ref = reference_sigreg(rows, dirs)
    assert float(ours) == pytest.approx(float(ref), rel=1e-4)
    # the first model's grid ([0, 3] at 17 knots) and its per-step rows give another number: the test can fail
    first = sigreg(z.transpose(0, 1), directions=dirs)
    assert abs(float(first) / float(ref) - 1) > 0.5


def planted_batch(contact: float, B: int = 4, L: int = 18) -> dict:
    gen = torch.Generator().manual_seed(1)
    touch = torch.rand(B, L, 7, generator=gen)
    touch[..., 6] = contact
    return dict(frames=torch.randint(0, 255, (B, L, 16, 16), dtype=torch.uint8, generator=gen),
                proprio=torch.randn(B, L, 4, generator=gen), touch=touch, actions=torch.randn(B, L, 2, generator=gen))


def tiny_reference(variant: str = "VFX", **over):
    cfg = make_config("tiny", variant=variant, encoder="reference", head_form="reference", sensor_horizons=(1, 4),
                      latent_horizon_weights=(1.0, 0.5), sensor_horizon_weights=(0.5, 0.25),
                      contact_weighting="frames", sigreg_pool="pooled", sigreg_knots=9, sigreg_t_max=5.0, **over)
    torch.manual_seed(0)
    return cfg, XJEPA(**model_kwargs(cfg, DIMS))


def test_paper_loss_weights_sum_the_horizons_as_the_reference_does():
    cfg, model = tiny_reference()
    loss, terms = model.loss(planted_batch(0.0), **loss_kwargs(cfg))
    expect = (terms["pred_1"] + 0.5 * terms["pred_4"] + 0.5 * terms["pred_16"] + cfg.sigreg_weight * terms["sigreg"]
              + terms["proprio"] + terms["touch"])
    assert float(loss.detach()) == pytest.approx(float(expect), rel=1e-5)
    # no Δ16 proprio / touch heads; the latent heads keep Δ16
    assert set(model.modal_heads["touch"]) == {"1", "4"} and "16" in model.latent_heads
    with pytest.raises(ValueError, match="no direct touch head"):
        model.forecast(torch.zeros(1, 18, cfg.width), torch.zeros(1, 18, 2), 16, "touch")
    l1, l4, l16 = torch.tensor(2.0), torch.tensor(3.0), torch.tensor(5.0)
    assert float(combine_horizons([l1, l4], [1, 4], (0.5, 0.25))) == pytest.approx(1.75)
    assert float(combine_horizons([l1, l4, l16], [1, 4, 16], (1.0, 0.5))) == pytest.approx(6.0)
    assert float(combine_horizons([l1, l4], [1, 4])) == pytest.approx(2.5)  # empty: the mean
    # a single-horizon run of the paper preset is single-horizon for every target
    single = XJEPA(**model_kwargs(make_config("tiny", horizons=(1,), sensor_horizons=(1, 4)), DIMS))
    assert single.sensor_horizons == (1,) and set(single.modal_heads["touch"]) == {"1"}
    for bad, match in ((dict(latent_horizon_weights=(1.0, 0.5, 0.5)), "give two"),
                       (dict(head_form="reference", head_layers=2), "applies to head_form='mlp' only"),
                       (dict(fuse_dim=64), "applies to encoder='reference' only"),
                       (dict(encoder="resnet"), "unknown encoder"),
                       (dict(contact_weighting="sum"), "unknown contact_weighting"),
                       (dict(sensor_horizons=(4,), horizons=(1,)), "share a horizon")):
        with pytest.raises(ConfigError, match=match):
            make_config("tiny", **bad)


@pytest.mark.parametrize("contact, ratio", [(1.0, 4.0), (0.0, 1.0)])
def test_frame_contact_weighting_scales_the_touch_term_by_the_mean_weight(contact, ratio):
    cfg, model = tiny_reference()
    kw = loss_kwargs(cfg)
    model.eval()  # no dropout: the two losses see the same forward pass
    frames = model.loss(planted_batch(contact), **kw)[1]["touch"]
    normalised = model.loss(planted_batch(contact), **{**kw, "contact_weighting": "normalised"})[1]["touch"]
    # every target frame in contact: Σ 4e / N is 4× the weighted mean Σ 4e / Σ 4; none: both are the MSE
    assert float(frames) == pytest.approx(ratio * float(normalised), rel=1e-5)


def test_reference_heads_and_encoder_have_the_released_form():
    cfg, model = tiny_reference()
    convs = [m for m in model.encoder.cnn.modules() if isinstance(m, torch.nn.Conv2d)]
    assert [c.kernel_size for c in convs] == [(3, 3)] * 4
    assert not any(isinstance(m, torch.nn.GroupNorm) for m in model.encoder.modules())
    head1, head4 = model.latent_heads["1"], model.latent_heads["4"]
    assert isinstance(head1, ReferenceDeltaHead) and head1.act is None and head1.bn is not None
    model.eval()
    h, a = torch.randn(5, cfg.width), torch.randn(5, 8)
    # the Δ1 latent head reads the state alone; a Δ > 1 head is affine in the state for a fixed action window
    assert torch.allclose(head1(h, a), head1(h, torch.randn(5, 2)))
    zero = head4(torch.zeros_like(h), a)
    assert torch.allclose(head4(3 * h, a) - zero, 3 * (head4(h, a) - zero), atol=1e-5)
    assert not math.isclose(float((head4(h, a) - head4(h, -a)).detach().abs().sum()), 0.0)


def test_every_variants_released_seed_0_run_is_beside_ours():
    # the paper-budget record shows the authors' run of the same variant and seed beside each of ours: every variant
    # of Table "targets" has its seed-0 run, one transcription (RUNS is the seed-0 view of MULTI_HORIZON)
    from pokeworld.published.release import released

    assert sorted(R.RUNS) == sorted(VARIANTS)
    for variant, run in R.RUNS.items():
        assert released(variant, 0) is run and run["source"].endswith("_s0_l0.02.json") and run["mlp"]
    assert released("V", 0)["ridge"]["log_k"] == -0.0191 and released("VX", 1) == {}
    assert released("VFX", 1)["source"].endswith("VFX_s1_l0.02.json")


def test_the_released_flow_sensor_runs_are_the_papers_coordinate_test_and_ledger_numbers():
    # the transcription ties to the paper's text: the coordinate test's glide-window γ 0.08 → 0.33 is the pair on the
    # glide-enriched split without / with log speed, the ledger's velocity 0.88 the velocity-only run's moving windows
    from pokeworld.experiments.coordinate import COORDINATE

    runs = R.FLOW_SENSOR_VFX
    assert (round(runs["fl_g"]["gamma_glide"], 2), round(runs["fl_g_ls"]["gamma_glide"], 2)) == \
        tuple(COORDINATE["gamma_glide_readout"])
    assert round(runs["fl"]["object_vel_moving"], 2) == COORDINATE["object_vel"][1]
    assert round(runs["fl"]["gamma_glide"], 2) < 0.05  # velocity alone leaves glide-window γ at the plateau
    for tag, run in runs.items():
        assert run["source"].endswith(f"VFX_s0_l0.02_{tag}.json")


def test_dose_one_is_the_released_flow_input_runs_on_the_glide_enriched_split():
    # Table "dose1"'s log k, velocity and glide-window γ are the release's _fl_g(_gwW) runs to two decimals, so its
    # weight 1 is that model (log k 0.42), not Table "targets"' VFX (0.50)
    from pokeworld.experiments.dose_glide import DOSE_GLIDE

    assert sorted(R.DOSE_GLIDE_RUNS) == sorted(DOSE_GLIDE)
    for w, tag in R.DOSE_GLIDE_RUNS.items():
        run, paper = R.FLOW_SENSOR_VFX[tag], DOSE_GLIDE[w]
        assert round(run["ridge"]["log_k"], 2) == paper["log_k"]
        assert round(run["object_vel_moving"], 2) == paper["object_vel"]
        assert round(run["gamma_glide"], 2) == paper["gamma_glide"]
    assert round(R.RUNS["VFX"]["ridge"]["log_k"], 2) != DOSE_GLIDE[1.0]["log_k"]


def _near(released: float, paper: float) -> bool:
    """The paper's two decimals of a released number, to one unit in the last place: the paper rounds some cells up
    (0.975 -> 0.98, V-recon's log m 0.1547 -> 0.16); a transcription slip or another run is off by more."""
    return abs(released - paper) <= 0.01 + 1e-9


def test_controls_dose_two_and_coverage_are_the_released_runs_but_one_cell():
    # Tables "controls" and "dose2" and the coverage cells are the release's runs to two decimals; the one exception,
    # V-recon's MLP log k (paper -0.10, released -0.0003), is a difference the ledger shows, not a transcription slip
    from pokeworld.experiments.controls import CONTROLS
    from pokeworld.experiments.coverage import COVERAGE
    from pokeworld.experiments.dose_touch import DOSE_TOUCH
    from pokeworld.published.paper import CONTROLS_MLP

    for key, run in R.CONTROL_RUNS.items():
        for q in ("log_m", "gamma", "log_k"):
            assert _near(run["ridge"][q], CONTROLS[key][q]), (key, q)
            if (key, q) != ("V-recon", "log_k"):
                assert _near(run["mlp"][q], CONTROLS_MLP[key][q]), (key, q)
        assert _near(run["object_pos_frame"], CONTROLS[key]["object_pos"]), key
        assert _near(run["object_vel_moving"], CONTROLS[key]["object_vel"]), key
    assert CONTROLS_MLP["V-recon"]["log_k"] - R.CONTROL_RUNS["V-recon"]["mlp"]["log_k"] < -0.09
    for w, run in R.DOSE_TOUCH_RUNS.items():
        assert all(_near(run["ridge"][q], DOSE_TOUCH[w][q]) for q in ("log_k", "log_m", "gamma")), w
    poor = R.CONTACT_POOR_VFX
    readings = {"log_k": poor["ridge"]["log_k"], "log_m": poor["ridge"]["log_m"], "object_pos": poor["object_pos_frame"],
                "object_vel": poor["object_vel_moving"]}
    assert all(_near(v, COVERAGE["contact_poor"][q]) for q, v in readings.items())
