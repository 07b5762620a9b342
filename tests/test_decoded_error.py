"""The decoded-error spectrum: it tells a head that misses the low-variance directions where position lives from one
that predicts every direction, and on a trained run its decoded direct error is the run's own measure.json one."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pokeworld.cli import main as cli
from pokeworld.diagnostics.decoded_error import band_edges, main, pooled_r2, spectrum


def planted(rng, n=4000, loud=4, quiet=12):
    """Latents whose variance sits in ``loud`` dimensions that carry no position, and position in ``quiet``
    dimensions with a thousandth of that variance."""
    pos = rng.uniform(-1, 1, (n, 2))
    z = np.empty((n, loud + quiet))
    z[:, :loud] = rng.normal(0, 1, (n, loud))
    z[:, loud:] = 0.03 * (pos @ rng.normal(size=(2, quiet)) + 0.05 * rng.normal(size=(n, quiet)))
    return z, pos


def test_bands_cover_every_component_once():
    assert band_edges(128) == [(0, 4), (4, 16), (16, 32), (32, 128)]
    assert band_edges(10) == [(0, 4), (4, 10)]


def test_a_head_that_misses_the_quiet_directions_scores_well_in_latent_space_and_fails_where_position_is(rng):
    z, pos = planted(rng)
    z_true = z[2000:]
    # the head is exact on the loud dimensions and adds an error of 0.1 on the quiet ones (their scale is ~0.03)
    misses = z_true + np.c_[np.zeros((2000, 4)), rng.normal(0, 0.1, (2000, 12))]
    s = spectrum(z[:2000], pos[:2000], z_true, misses)
    assert s["latent_r2"] > 0.9  # the MSE view: the error is a small share of the variance
    loud, *_, last = s["bands"]
    assert loud["variance_share"] > 0.99 and loud["head_r2"] > 0.99
    assert loud["position_r2_through"] < 0.1 and last["position_r2_through"] > 0.95  # position is in the quiet part
    assert all(b["head_r2"] < 0 for b in s["bands"][1:])
    # the control: an error proportional to each direction's own scale leaves every band predicted
    scale = z_true.std(0)
    even = z_true + 0.1 * scale * rng.normal(size=z_true.shape)
    assert all(b["head_r2"] > 0.95 for b in spectrum(z[:2000], pos[:2000], z_true, even)["bands"])


def test_pooled_r2_scores_a_perfect_and_a_mean_predictor():
    y = np.random.default_rng(0).normal(size=(100, 3))
    assert pooled_r2(y, y) == 1.0
    assert pooled_r2(y, np.broadcast_to(y.mean(0), y.shape)) == pytest.approx(0.0)


def test_shapes_that_disagree_are_refused(rng):
    with pytest.raises(ValueError, match="latent shapes disagree"):
        spectrum(rng.normal(size=(50, 8)), rng.normal(size=(50, 2)), rng.normal(size=(10, 8)),
                 rng.normal(size=(10, 7)))


def test_on_a_trained_run_the_decoded_direct_error_is_the_measured_one(tmp_path, capsys):
    store, run, out = tmp_path / "store", tmp_path / "run", tmp_path / "spectrum.json"
    assert cli(["generate", "--preset", "tiny", str(store)]) == 0
    assert cli(["train", "--preset", "tiny", "--data", str(store), "--out", str(run)]) == 0
    assert cli(["probe", "--preset", "tiny", str(run)]) == 0
    assert main([str(run), "--preset", "tiny", "--out", str(out)]) == 0
    record = json.loads(out.read_text())
    row = record["runs"]["run"]
    assert str(tmp_path) not in record["provenance"]["command"]  # run folders by name, no machine paths
    measured = json.loads((run / "measure.json").read_text())["prediction"]
    assert row["decoded"]["direct"] == pytest.approx(measured["direct16"], rel=1e-5)
    assert row["decoded"]["static"] == pytest.approx(measured["static16"], rel=1e-5)
    assert sum(b["variance_share"] for b in row["bands"]) == pytest.approx(1.0)
    assert f"wrote {out}" in capsys.readouterr().out


def test_a_folder_that_is_not_a_run_gets_one_line(tmp_path, capsys):
    assert main([str(tmp_path), "--out", str(tmp_path / "x.json")]) == 2
    assert "is not a run directory" in capsys.readouterr().err
