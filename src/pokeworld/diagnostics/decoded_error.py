"""Why a decoded direct-Δ error can sit above the static baseline while the Δ head's latent error is small.

The prediction table decodes the direct head's Δ=16 latent to position through a ridge decoder fit on true
encoder latents (:func:`pokeworld.evaluate.prediction.prediction_quality`). The head is trained by a plain MSE on
the latent, which spends its accuracy where the latent's variance is; the decoder reads position wherever it is
linearly available, low-variance directions included. When position lives in directions that hold little of the
latent's variance, a head that predicts the latent well (high variance-weighted R²) can still decode to a worse
position than the static latent. This measures that split on the latent's principal components:

- for each band of components (ordered by variance): its share of the variance, and the head's R² on the band
  (1 − its squared error over the band's total variance about the mean);
- how much of position the leading components alone carry (ridge-free least squares, in-sample);
- the decoded direct and static errors and the decoder floor, as the prediction table computes them (the direct
  error equals the run's measure.json ``prediction.direct16``).

    python scripts/decoded_error_spectrum.py out/map/runs/VF-…-tokensTrue-s0 out/map/runs/VFX-…-standard-s0 \
        --out docs/results/decoded_error_spectrum_cpu.json
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

from .. import __version__
from ..data import load
from ..evaluate import measure
from ..evaluate.prediction import HORIZON, direct_latents, future_windows, position_decoder, position_error
from ..evaluate.probes import probe_latents
from ..evaluate.tables import git_commit
from ..io import write_json
from ..run_store import trained_store
from ..rundir import load_model

BANDS = (4, 16, 32)
"""Upper edges of the principal-component bands (the last band runs to the latent's dimension)."""


def band_edges(dim: int, bands: tuple[int, ...] = BANDS) -> list[tuple[int, int]]:
    """[(0, 4), (4, 16), (16, 32), (32, dim)] for the default bands, clipped to ``dim``."""
    cuts = [b for b in bands if b < dim] + [dim]
    return list(zip([0, *cuts[:-1]], cuts))


def pooled_r2(y: np.ndarray, p: np.ndarray) -> float:
    """1 − Σ squared error / Σ squared deviation about the column means, pooled over every column."""
    sst = float(((y - y.mean(0)) ** 2).sum())
    return 1.0 - float(((y - p) ** 2).sum()) / sst if sst > 0 else float("nan")


def spectrum(z_frames: np.ndarray, pos_frames: np.ndarray, z_true: np.ndarray, z_pred: np.ndarray,
             bands: tuple[int, ...] = BANDS) -> dict:
    """The head's accuracy and position's share per principal band of the latent.

    Args:
        z_frames: (N, D) latents the components are taken from, with ``pos_frames`` (N, P) their positions.
        z_true, z_pred: (W, D) the head's target latents and its predictions.
    Returns:
        ``latent_r2`` (the head's variance-weighted R² over every dimension) and ``bands``: one row per band
        with ``pcs`` (first, end), ``variance_share``, ``head_r2`` and ``position_r2_through`` (position's
        least-squares R² from every component up to the band's end, mean over position coordinates).
    """
    if z_frames.ndim != 2 or z_true.shape != z_pred.shape or z_true.shape[1] != z_frames.shape[1]:
        raise ValueError(f"latent shapes disagree: frames {z_frames.shape}, target {z_true.shape}, "
                         f"prediction {z_pred.shape}")
    mu = z_frames.mean(0)
    ev, vecs = np.linalg.eigh(np.cov((z_frames - mu).T))
    order = np.argsort(ev)[::-1]
    ev, vecs = np.clip(ev[order], 0, None), vecs[:, order]
    scores = (z_frames - mu) @ vecs
    s_true, s_pred = (z_true - mu) @ vecs, (z_pred - mu) @ vecs
    rows = []
    for lo, hi in band_edges(len(ev), bands):
        X = np.c_[scores[:, :hi], np.ones(len(scores))]
        coef, *_ = np.linalg.lstsq(X, pos_frames, rcond=None)
        fit = X @ coef
        pos_r2 = np.mean([pooled_r2(pos_frames[:, j:j + 1], fit[:, j:j + 1]) for j in range(pos_frames.shape[1])])
        rows.append({"pcs": [lo, hi], "variance_share": float(ev[lo:hi].sum() / ev.sum()),
                     "head_r2": pooled_r2(s_true[:, lo:hi], s_pred[:, lo:hi]),
                     "position_r2_through": float(pos_r2)})
    return {"latent_r2": pooled_r2(z_true, z_pred), "bands": rows}


def run_spectrum(run: Path, cfg: measure.MeasureConfig, data: str | None = None, horizon: int = HORIZON,
                 stride: int = 4) -> dict:
    """:func:`spectrum` of one run's direct Δ=``horizon`` head on the probe-test windows, beside the decoded errors
    of the prediction table, computed as :func:`~pokeworld.evaluate.prediction.prediction_quality` does with the
    measurement preset ``cfg`` (same latents, decoder, windows and seed: ``direct16`` equals the run's measure.json)."""
    model = load_model(run, map_location="cpu").eval()
    if horizon not in model.horizons:
        raise ValueError(f"{run} has no direct head for Δ={horizon} (horizons {model.horizons})")
    ds = load(data or trained_store(run, "decoded-error"))
    context, test_eps = cfg.context, ds.episodes("probe_test")
    lat_fit, lat_test = probe_latents(model, ds, cfg)
    dec = position_decoder(ds, lat_fit, ds.episodes("probe_fit"), np.random.default_rng(cfg.seed))
    w, acts, z, pos = future_windows(ds, lat_test, test_eps, context + horizon, stride)
    z_pred = direct_latents(model, lat_test, w, acts, horizon, context)
    frames = lat_test.z.reshape(-1, lat_test.z.shape[-1])
    out = spectrum(frames, ds.labels["object_pos"][test_eps].reshape(len(frames), -1), z[:, -1], z_pred)
    out.update(tokens=bool(getattr(model, "tokens", False)), horizon=horizon, windows=len(w),
               decoded={"direct": position_error(dec.predict(z_pred), pos[:, -1]),
                        "static": position_error(dec.predict(z[:, context - 1]), pos[:, -1]),
                        "probe_error": position_error(dec.predict(z[:, -1]), pos[:, -1])})
    return out


def summary(name: str, row: dict) -> str:
    d = row["decoded"]
    bands = "; ".join(f"PCs {b['pcs'][0]}–{b['pcs'][1]}: var {b['variance_share']:.3f}, head R² "
                      f"{b['head_r2']:+.2f}, position R² through {b['position_r2_through']:.2f}" for b in row["bands"])
    return (f"{name}: Δ={row['horizon']} latent R² {row['latent_r2']:+.3f}; decoded direct {d['direct']:.3f} / static "
            f"{d['static']:.3f} / floor {d['probe_error']:.3f}; {bands}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", type=Path, nargs="+", help="run directories (token or global-embedding models)")
    ap.add_argument("--data", default=None, help="corpus to read (default: each run's own training store)")
    ap.add_argument("--preset", default="cpu", help="measurement preset whose seed the decoder's subsample uses")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args(argv)
    for p in a.runs:
        if not (p / "config.json").exists():
            print(f"error: {p} is not a run directory (no config.json); pass a folder `pokeworld train` wrote",
                  file=sys.stderr)
            return 2
    cfg = measure.make_config(a.preset)
    torch.manual_seed(cfg.seed)
    # run folders by name only: a record names no machine's paths
    command = "python scripts/decoded_error_spectrum.py " + " ".join(f"RUNS/{p.name}" for p in a.runs) + \
        (" --data DATA" if a.data else "") + f" --preset {a.preset} --out {a.out.name}"
    out = {"preset": a.preset, "bands": list(BANDS), "runs": {},
           "provenance": {"pokeworld": __version__, "git": git_commit(), "command": command}}
    for i, run in enumerate(a.runs):
        print(f"[decoded-error] {i + 1}/{len(a.runs)} {run.name}", flush=True)
        row = out["runs"][run.name] = run_spectrum(run, cfg, a.data)
        print(summary(run.name, row), flush=True)
    write_json(a.out, out)
    print(f"[decoded-error] wrote {a.out}")
    return 0
