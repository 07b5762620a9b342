"""Where a Gaussian-NLL run puts its learned precision (docs/results/frontier_cpu.md, "Controls").

The heteroscedastic NLL ``0.5·(e^{-s}(y-μ)² + s)`` weighs each target frame's squared error by its
predicted precision e^{-s}. This prints, per horizon Δ, the mean precision of the latent heads (and of the
touch heads when ``gnll_heads='all'``) on target frames in finger contact and on contact-free target frames
(probe-test episodes, one seeded batch of windows), so the effective weight the objective gives the impact
frames — where stiffness lives — can be compared with the MSE run's fixed contact weight.

    python scripts/nll_precision.py DATA RUN [RUN ...] [--windows 256] [--out FILE.json]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from ..data import load
from ..errors import ConfigError
from ..io import write_json
from ..losses import nll_precision
from ..rundir import load_model
from ..train.sampler import WindowSampler


def precisions(model, ds, windows: int, window: int = 24, seed: int = 0) -> dict:
    if model.objective != "gnll":
        raise ConfigError(f"{model.objective!r} run: precisions exist only for objective='gnll'")
    s = WindowSampler(ds, ds.episodes("probe_test"), model.image_size, window, torch.device("cpu"), seed=seed)
    b = s.sample(windows)
    out = {}
    with torch.no_grad():
        h = model.trunk(model.encode(b["frames"], b["proprio"], b["touch"]), b["actions"])
        for d in model.horizons:
            contact = b["touch"][:, d:, model.contact_channel] > 0.5  # target frame t+Δ in finger contact
            _, lv = model.predict(h, b["actions"], d, return_logvar=True)
            prec = {"latent": nll_precision(lv[:, :window - d]).mean(-1)}
            if "touch" in model.modal_heads:
                _, lv_touch = model.forecast(h, b["actions"], d, "touch", return_logvar=True)
                if lv_touch is not None:  # gnll_heads='all'
                    prec["touch"] = nll_precision(lv_touch[:, :window - d]).mean(-1)
            out[str(d)] = {"contact_share": float(contact.float().mean()),
                           **{f"{k}_contact": float(p[contact].mean()) for k, p in prec.items()},
                           **{f"{k}_free": float(p[~contact].mean()) for k, p in prec.items()}}
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data")
    ap.add_argument("runs", nargs="+")
    ap.add_argument("--windows", type=int, default=256)
    ap.add_argument("--out", default="")
    a = ap.parse_args(argv)
    torch.manual_seed(0)
    ds = load(a.data)
    res = {Path(r).name: precisions(load_model(r), ds, a.windows) for r in a.runs}
    for name, rows in res.items():
        print(name)
        for d, row in rows.items():
            print(f"  Δ={d}: " + ", ".join(f"{k} {v:.2f}" if k == "contact_share" else f"{k} {v:.0f}"
                                       for k, v in row.items()))
    if a.out:
        write_json(Path(a.out), res)
