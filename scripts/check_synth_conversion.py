"""Compare a converted store of a synthetic RH20T-layout corpus with the corpus's ground truth.

    python scripts/check_synth_conversion.py STORE ROOT [--out FILE.json]

STORE is the output of ``pokeworld rh20t-convert ROOT ...``, ROOT the output of ``pokeworld rh20t-synth``.
Reports two separate things (docs/rh20t.md, "What conversion gives"): conversion mechanics (the stored
signals against ``expected_*``, the linear interpolation of the recorded samples after the drop rules:
float precision when correct) and sampling loss (against the noise-free simulator signal), plus whether
the skip / camera / F/T-source counts are exactly the ones the generator planted.
"""

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from pokeworld import data
from pokeworld.real.synthetic import load_truth


def check(store: str, root: str) -> dict:
    ds = data.load(store)
    man = json.loads((Path(root) / "truth" / "manifest.json").read_text())
    rep = json.loads((Path(store) / "conversion_report.json").read_text())
    T1 = ds.labels["force"].shape[1]
    err = {"force_n": 0.0, "torque_nm": 0.0, "tcp_pos_m": 0.0}
    f_true, f_conv, c_true, c_conv, pos_err = [], [], [], [], []
    for e in range(ds.num_episodes):
        row = ds.manifest["scenes"][int(ds.params["scene_index"][e])]
        ci = int(ds.params["chunk_index"][e])
        tr, sl = load_truth(root, row["name"]), slice(ci * T1, (ci + 1) * T1)
        err["force_n"] = max(err["force_n"], float(np.abs(ds.labels["force"][e] - tr["expected_force"][sl]).max()))
        err["torque_nm"] = max(err["torque_nm"], float(np.abs(ds.labels["torque"][e] - tr["expected_torque"][sl]).max()))
        err["tcp_pos_m"] = max(err["tcp_pos_m"], float(np.abs(ds.labels["tcp_pos"][e] - tr["expected_tcp_pos"][sl]).max()))
        f_true.append(tr["force"][sl])
        f_conv.append(ds.labels["force"][e])
        c_true.append(tr["contact"][sl])
        c_conv.append(ds.labels["contact"][e])
        pos_err.append(float(np.abs(ds.labels["tcp_pos"][e] - tr["tcp_pos"][sl]).max()))
    ft, fc = np.concatenate(f_true), np.concatenate(f_conv)
    ct, cc = np.concatenate(c_true), np.concatenate(c_conv)
    counts_match = {
        "skip_counts": rep["skip_counts"] == man["expected_skip_counts"],
        "scenes_converted": rep["scenes_converted"] == man["expected_converted"],
        "ft_source_counts": rep["ft_source_counts"] == man["expected_ft_source_counts"],
    }
    return {
        "store": store, "root": root, "episodes": int(ds.num_episodes), "scenes_converted": rep["scenes_converted"],
        "skip_counts": rep["skip_counts"], "camera_counts": rep["camera_counts"],
        "ft_source_counts": rep["ft_source_counts"], "counts_match_planted": counts_match,
        "max_abs_error_vs_expected": err,
        "force_r2_vs_noise_free_truth": float(1 - ((fc - ft) ** 2).sum() / ((ft - ft.mean(0)) ** 2).sum()),
        "force_max_abs_error_vs_truth_n": float(np.abs(fc - ft).max()),
        "tcp_max_abs_error_vs_truth_m": max(pos_err),
        "contact_label_agreement": float((ct == cc).mean()),
        "contact_share": float(cc.mean()),
        "onset_base_rate": ds.manifest.get("onset_base_rate"),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("store")
    ap.add_argument("root")
    ap.add_argument("--out", default="")
    a = ap.parse_args(argv)
    for p, what in ((a.store, "store"), (Path(a.root) / "truth" / "manifest.json", "truth manifest")):
        if not Path(p).exists():
            print(f"error: {what} {p} does not exist", file=sys.stderr)
            return 2
    res = check(a.store, a.root)
    text = json.dumps(res, indent=2)
    print(text)
    if a.out:
        tmp = Path(a.out).with_suffix(".tmp")
        tmp.write_text(text + "\n")
        tmp.replace(a.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
