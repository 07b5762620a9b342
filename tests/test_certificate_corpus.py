"""The certificates' own fit corpus: same generator on disjoint seeds, every episode a fit episode, nested prefixes,
scored on the store's probe-test split; refused on stores no generator config describes."""

import json

import numpy as np
import pytest

from pokeworld import certificate_corpus, certify
from pokeworld.data import load, save
from pokeworld.errors import ConfigError, DataError
from pokeworld.sim import generate


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    out = tmp_path_factory.mktemp("cc") / "bias"
    generate.run(generate.make_config("tiny", out=str(out), corpus="bias1.5", seed=3, num_episodes=120, batch_envs=120))
    return out


def test_certificate_corpus_is_the_stores_generator_on_independent_seeds(store):
    ds = load(store)
    fit = certificate_corpus.ensure(ds, store, 40)
    assert fit.num_episodes == 40 and (fit.split == 1).all()  # every episode is a fit episode
    mine, theirs = dict(fit.manifest["config"]), dict(ds.manifest["config"])
    for d in (mine, theirs):
        for k in ("seed", "num_episodes", "split_fractions"):
            d.pop(k)
    assert mine == theirs and fit.manifest["corpus"] == "bias1.5"  # same physics, ranges, policy and corpus
    assert fit.manifest["seed"] == certificate_corpus.fit_seed(3) != 3
    # independent episodes: no hidden-parameter draw of the store reappears
    assert not np.isin(fit.params["log_m"], ds.params["log_m"]).any()
    again = certificate_corpus.ensure(ds, store, 40)  # found up to date, not regenerated
    assert again.manifest["content_sha256"] == fit.manifest["content_sha256"]


def test_certify_fits_on_the_certificate_corpus_and_scores_on_the_store(store):
    cfg = certify.make_config("tiny", data=str(store), estimators=("linear", "drag"), kinds=("contact",),
                              fit_episodes=30, targets=("log_m", "gamma", "log_k"))
    path = certify.run(cfg)
    res = json.loads(path.read_text())
    ds, fit = load(store), load(certificate_corpus.path(store, 30))
    assert res["fit_corpus"]["source"] == "certificate corpus" and res["fit_corpus"]["episodes"] == 30
    assert res["fit_corpus"]["content_sha256"] == fit.manifest["content_sha256"]
    from pokeworld.windows import make_windows

    expect_test = len(make_windows(ds, ds.episodes("probe_test"), cfg.window, cfg.stride).kind("contact"))
    assert res["counts"]["contact"]["test"] == expect_test
    expect_fit = len(make_windows(fit, np.arange(30), cfg.window, cfg.stride).kind("contact"))
    assert res["counts"]["contact"]["fit"] == min(expect_fit, cfg.max_windows)
    own = certify.certify(ds, certify.make_config("tiny", estimators=("linear",), kinds=("contact",)))
    assert own["fit_corpus"] == {"source": "store probe-fit split", "episodes": int((ds.split == 1).sum())}


def test_more_certificate_episodes_recover_a_parameter_better(store):
    """The fit-size curve can come out either way: a ridge certificate of the persistent force bias fit on 8
    certificate episodes reads nothing, one fit on 80 reads it (the 8 are the first 8 of the 80)."""
    ds = load(store)
    fit = certificate_corpus.ensure(ds, store, 80)
    r2 = {}
    for n in (8, 80):
        cfg = certify.make_config("tiny", estimators=("linear",), kinds=("all",), fit_episodes=n, targets=("bias_x",))
        r2[n] = certify.certify(ds, cfg, fit)["estimators"]["linear"]["all"]["bias_x"]
    assert r2[8] < 0.1 and r2[80] > 0.3, r2


def test_certificate_corpus_needs_a_generated_store_and_enough_episodes(store, tmp_path):
    ds = load(store)
    foreign = ds.subset(np.arange(ds.num_episodes))
    foreign.manifest = {**ds.manifest, "generator": "pokeworld.real.rh20t"}
    save(foreign, tmp_path / "real")
    with pytest.raises(ConfigError, match="fit_episodes=0"):
        certify.run(certify.make_config("tiny", data=str(tmp_path / "real"), estimators=("linear",), fit_episodes=10))
    fit = certificate_corpus.ensure(ds, store, 40)
    with pytest.raises(DataError, match="only 40"):
        certify.certify(ds, certify.make_config("tiny", estimators=("linear",), fit_episodes=80), fit)
    with pytest.raises(ConfigError, match="fit_episodes"):
        certify.make_config("tiny", fit_episodes=-1)


def test_plateau_is_where_more_episodes_stop_helping():
    from pokeworld.certificate_curve import plateau

    assert plateau([(240, 0.80), (480, 0.84), (960, 0.85), (1920, 0.85)], 0.02) == 480
    assert plateau([(240, 0.05), (480, 0.44), (960, 0.67), (1920, 0.81), (3840, 0.89)], 0.02) is None  # rising
    assert plateau([(240, 0.84), (480, 0.83)], 0.02) == 240


def test_a_window_cap_below_the_certificate_corpus_is_recorded_not_silent(store, capsys):
    """A cap undoes the corpus (the GRU oracle is fit-set limited below its plateau): a capped fit on a certificate
    corpus says how many windows it kept of how many, in certificates.json and on stdout; an uncapped one does not."""
    ds = load(store)
    fit = certificate_corpus.ensure(ds, store, 40)
    capped = certify.certify(ds, certify.make_config("tiny", estimators=("linear",), kinds=("contact",),
                                                     fit_episodes=40, max_windows=50), fit)
    counts = capped["counts"]["contact"]
    assert counts["fit"] == 50 < counts["fit_available"]
    assert len(capped["warnings"]) == 1 and "keeps 50 of the 40-episode" in capped["warnings"][0]
    assert f"--max-windows to at least {counts['fit_available']}" in capped["warnings"][0]
    assert "warning" in capsys.readouterr().out
    whole = certify.certify(ds, certify.make_config("tiny", estimators=("linear",), kinds=("contact",),
                                                    fit_episodes=40, max_windows=10**6), fit)
    assert whole["warnings"] == [] and whole["counts"]["contact"]["fit"] == counts["fit_available"]
