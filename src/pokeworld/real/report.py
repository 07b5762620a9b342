"""Tables and the scissors figure of ``pokeworld real``, shaped like the paper's App. C, paper beside ours.

Paper numbers come from :mod:`pokeworld.published.paper` and sit in their own columns; a cell of ours is
"—" when the run or metric is missing (never a paper value).
"""

from __future__ import annotations

from pathlib import Path

from ..io import remove_own_file, save_figure_as, save_text
from ..published import paper as P

DASH = "—"


def fmt(v, digits: int = 2, signed: bool = False) -> str:
    if v is None:
        return DASH
    return f"{v:+.{digits}f}" if signed else f"{v:.{digits}f}"


def pair(a, b, digits: int = 2) -> str:
    return f"{fmt(a, digits)} / {fmt(b, digits)}"


def ppair(p) -> str:
    return DASH if p is None else pair(*p)


def metrics(results: dict, run: str | None, store: str, which: str = "trained") -> dict | None:
    """Evaluation dict of ``run`` on ``store`` (None when missing)."""
    r = results["runs"].get(run) if run else None
    return None if r is None else r["evals"].get(store, {}).get(which)


def get(m: dict | None, *path):
    for k in path:
        if m is None or not isinstance(m, dict) or k not in m:
            return None
        m = m[k]
    return m


def force(m, t):
    return get(m, "readout", "ridge", "force", t)


def pos(m, t):
    return get(m, "readout", "ridge", "tcp_pos", t)


def auc(m, t):
    return get(m, "onset", "ridge", t)


def pred(m, key, t="iid"):
    return get(m, "prediction", t, key)


def run_name(results: dict, store: str, variant: str, steps_factor: float = 1.0) -> str | None:
    for name, r in results["runs"].items():
        if r["store"] == store and r["variant"] == variant and r["steps_factor"] == steps_factor:
            return name
    return None


def table(head: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)] + ["| " + " | ".join(r) + " |" for r in rows]


# --------------------------------------------------------------------------- tables
def kuka_table(results: dict, store: str = "kuka") -> list[str]:
    variants = results["config"]["variants"]
    rows = []
    static = None
    for v in variants:
        m = metrics(results, run_name(results, store, v), store)
        p = P.REAL_KUKA.get(v, {})
        static = static if static is not None else pred(m, "static16")
        rows.append([v, pair(force(m, "iid"), force(m, "ood")), ppair(p.get("force")),
                     pair(pos(m, "iid"), pos(m, "ood")), ppair(p.get("position")),
                     pair(pred(m, "direct16"), pred(m, "rollout16"), 1), fmt(p.get("pred16"), 1),
                     pair(auc(m, "iid"), auc(m, "ood")), ppair(p.get("auc"))])
    head = ["variant", "force IID/OOD", "paper", "position IID/OOD", "paper", "16-step direct/rollout (cm)",
            "paper 16-step", "AUC IID/OOD", "paper"]
    return (["## KUKA (cfg7): all variants (Table \"kuka\")", ""] + table(head, rows)
            + ["", f"Static 16-step baseline (decoded, IID): ours {fmt(static, 1)} cm; paper "
                   f"{P.REAL_KUKA_STATIC16} cm.", ""])


def viewpoint_table(results: dict) -> list[str]:
    cams = {"far": "kuka", "close": "kuka_close", "two_view": "kuka_two_view"}
    camera_only = [v for v in results["config"]["variants"] if v in ("V", "VX", "VX_t", "VX_p")]
    rows, vfx = [], []
    for cam, store in cams.items():
        vx = metrics(results, run_name(results, store, "VX"), store)
        best, best_v = None, None
        for v in camera_only:
            m = metrics(results, run_name(results, store, v), store)
            if pos(m, "iid") is not None and (best is None or pos(m, "iid") > pos(best, "iid")):
                best, best_v = m, v
        p = P.REAL_VIEWPOINT[cam]
        rows.append([cam, fmt(force(vx, "iid"), signed=True), fmt(p["force"], signed=True),
                     pair(pos(best, "iid"), pos(best, "ood")) + (f" ({best_v})" if best_v else ""),
                     ppair(p["position"]), fmt(pred(vx, "direct16"), 1), fmt(p["pred16"], 1)])
        f = metrics(results, run_name(results, store, "VFX"), store)
        vfx.append(f"{cam}: position {fmt(pos(f, 'iid'))}, force {fmt(force(f, 'iid'))}")
    head = ["camera", "camera-only force (VX, IID)", "paper", "camera-only position IID/OOD (best variant)",
            "paper", "16-step (VX direct, cm)", "paper"]
    return (["## Viewpoint selects observables (cfg7; Table \"viewpoint\")", ""] + table(head, rows)
            + ["", "VFX across viewpoints (ours, IID): " + "; ".join(vfx)
               + f". Paper: position {P.REAL_VIEWPOINT_VFX['position']}, force "
                 f"{P.REAL_VIEWPOINT_VFX['force_range'][0]}–{P.REAL_VIEWPOINT_VFX['force_range'][1]}.", ""])


def scale_label(results: dict, scale: float) -> str:
    info = results.get("store_info", {}).get("flexiv", {})
    total = info.get("scenes")
    if scale == 1.0:
        return f"all ({total})" if total else "all"
    return f"{scale:g}" if scale > 1 else f"{scale:g}" + (f" ({round(scale * total)})" if total else "")


def _paper_scale(scale: float, scales: list[float]) -> int | None:
    """The paper's scale point that ours stands for: by position in the sorted list of three."""
    if scale > 1 and int(scale) in (800, 2000):
        return int(scale)
    if scale == 1.0:
        return P.REAL_CFG1_SCENES
    order = sorted(scales)
    return (800, 2000, P.REAL_CFG1_SCENES)[order.index(scale)] if len(order) == 3 else None


def scaling_rows(results: dict) -> list[tuple[str, float, float, dict | None]]:
    out = []
    for name, r in results["runs"].items():
        if r["experiment"] == "scaling" or (r["store"].startswith("flexiv") and r["variant"] in results["config"]["arms"]):
            out.append((r["variant"], r["scale"], r["steps_factor"], metrics(results, name, "flexiv")))
    return out


def cfg1_table(results: dict) -> list[str]:
    c = results["config"]
    scales = list(c["scales"])
    rows, static = [], None
    for arm in c["arms"]:
        for s, factor in [(s, 1.0) for s in scales] + ([(1.0, c["compute_control"])] if c["compute_control"] else []):
            store = "flexiv" if s == 1.0 else f"flexiv@{s:g}"
            m = metrics(results, run_name(results, store, arm, factor), "flexiv")
            static = static if static is not None else pred(m, "static16")
            ps = _paper_scale(s, scales) if factor == 1.0 else None
            p = P.REAL_CFG1.get(arm, {}).get(ps, {}) if ps else {}
            label = scale_label(results, s) + (f" ×{factor:g} compute" if factor != 1.0 else "")
            rows.append([arm, label, pair(force(m, "iid"), force(m, "ood")), ppair(p.get("force")),
                         pair(pos(m, "iid"), pos(m, "ood")), ppair(p.get("position")),
                         fmt(pred(m, "direct16"), 1), fmt(p.get("pred16"), 1), fmt(auc(m, "ood")),
                         fmt(p.get("auc_ood")), str(ps or DASH)])
    head = ["arm", "scenes", "force IID/OOD", "paper", "pos. IID/OOD", "paper", "16-step direct (cm)", "paper",
            "AUC OOD", "paper", "paper scenes"]
    return (["## The four-arm factorial across scale (cfg1; Table \"cfg1\")", ""] + table(head, rows)
            + ["", f"Static 16-step baseline (decoded, IID): ours {fmt(static, 1)} cm; paper {P.REAL_CFG1_STATIC16} cm. "
                   f"Paper notes: V position under the +50 % compute control {P.REAL_CFG1_NOTES['V_position_compute_control']}, "
                   f"V open-loop 16-step rollout at full scale {P.REAL_CFG1_NOTES['V_rollout16_full']} cm.", ""])


def cross_table(results: dict) -> list[str]:
    def col(store, v):
        return metrics(results, run_name(results, store, v), store)

    cells = {(v, k): col(s, v) for v in ("V", "VFX") for k, s in (("cfg7", "kuka"), ("cfg1", "flexiv"))}
    pc = P.REAL_CROSS
    spec = [("Position readout (IID)", lambda m: pos(m, "iid"), lambda p: p["position"][0], 2),
            ("Position readout (OOD)", lambda m: pos(m, "ood"), lambda p: p["position"][1], 2),
            ("Force readout (OOD)", lambda m: force(m, "ood"), lambda p: p.get("force_ood"), 2),
            ("Contact anticipation AUC (OOD)", lambda m: auc(m, "ood"), lambda p: p["auc_ood"], 2),
            ("16-step prediction (IID, cm; ours direct)", lambda m: pred(m, "direct16"), lambda p: p["pred16"], 1),
            ("static baseline (cm)", lambda m: pred(m, "static16"), lambda p: p["static16"], 1)]
    rows = []
    for label, fn, pfn, d in spec:
        row = [label]
        for v in ("V", "VFX"):
            for k in ("cfg7", "cfg1"):
                row += [fmt(fn(cells[(v, k)]), d), fmt(pfn(pc[v][k]), d)]
        rows.append(row)
    head = ["", "V cfg7", "paper", "V cfg1", "paper", "VFX cfg7", "paper", "VFX cfg1", "paper"]
    return ["## Cross-embodiment comparison (Table \"crossemb\")", ""] + table(head, rows) + [""]


def untrained_table(results: dict) -> list[str]:
    store = "flexiv" if run_name(results, "flexiv", "VFX") else "kuka"
    rows = []
    for v in ("VFX", "V"):
        m = metrics(results, run_name(results, store, v), store, "untrained")
        p = P.REAL_UNTRAINED[v]
        d16 = pred(m, "direct16")
        rows.append([f"{v}, untrained", pair(force(m, "iid"), force(m, "ood")), ppair(p["force"]),
                     pair(pos(m, "iid"), pos(m, "ood")), ppair(p["position"]),
                     fmt(None if d16 is None else d16 / 100, 2) + " m", f"{p['pred16_m']:g} m",
                     pair(auc(m, "iid"), auc(m, "ood")), ppair(p["auc"])])
    retention = []
    # the variants that were trained on this store: the scaling arms on cfg1, the kuka variants on cfg7
    for arm in results["config"]["arms" if store == "flexiv" else "variants"]:
        m = metrics(results, run_name(results, store, arm), store)
        retention.append(f"{arm} {fmt(force(m, 'ood'))}")
    u = metrics(results, run_name(results, store, "VFX"), store, "untrained")
    head = ["architecture", "force IID/OOD", "paper", "position IID/OOD", "paper", "16-step direct", "paper",
            "AUC IID/OOD", "paper"]
    return ([f"## Untrained-encoder bounds (Table \"rand\"; store {store})", ""] + table(head, rows)
            + ["", f"Force retention, held-out tasks (Fig. \"forceread\"): ours {', '.join(retention)}; "
                   f"untrained VFX bound {fmt(force(u, 'ood'))}. Paper: VF {P.REAL_FORCE_RETENTION['VF']}, "
                   f"untrained bound {P.REAL_FORCE_RETENTION['untrained_VFX']}.", ""])


def forecast_table(results: dict) -> list[str]:
    store = "flexiv" if run_name(results, "flexiv", "VFX") else "kuka"
    rows = []
    models = {v: metrics(results, run_name(results, store, v), store) for v in ("VFX", "VX")}
    for v, m in models.items():
        row = [v]
        for d in ("1", "4"):
            f = get(m, "forecast", d)
            row += [pair(get(f, "iid", "model"), get(f, "ood", "model")), ppair(P.REAL_FORECAST[v].get(int(d)))]
        rows.append(row)
    ref = next((m for m in models.values() if m is not None), None)
    row = ["persistence"]
    for d in ("1", "4"):
        f = get(ref, "forecast", d)
        row += [pair(get(f, "iid", "persistence"), get(f, "ood", "persistence")),
                ppair(P.REAL_FORECAST["persistence"].get(int(d)))]
    rows.append(row)
    row = ["persistence, fitted (ridge on F_t; ours only)"]
    for d in ("1", "4"):
        f = get(ref, "forecast", d)
        row += [pair(get(f, "iid", "persistence_fit"), get(f, "ood", "persistence_fit")), DASH]
    rows.append(row)
    head = ["", "Δ=1 (0.1 s) IID/OOD", "paper", "Δ=4 (0.4 s) IID/OOD", "paper"]
    lines = [f"## Future-force forecasting (Table \"futforce\"; store {store})", ""] + table(head, rows) + [""]
    # across scale: held-out Δ=4 forecast and the paired scene-bootstrap CI of model − persistence
    c = results["config"]
    srows = []
    for arm in ("VFX", "VX") if "scaling" in results["experiments"] else ():
        if arm not in c["arms"]:
            continue
        for s in c["scales"]:
            st = "flexiv" if s == 1.0 else f"flexiv@{s:g}"
            f = get(metrics(results, run_name(results, st, arm), "flexiv"), "forecast", "4", "ood")
            ps = _paper_scale(s, list(c["scales"]))
            pv = P.REAL_FORECAST_SCALING.get(arm, {}).get(ps)
            pci = P.REAL_FORECAST_CI.get(arm, {}).get(ps) or P.REAL_FORECAST_CI.get(arm, {}).get("every scale")
            ci = get(f, "ci")
            srows.append([arm, scale_label(results, s), fmt(get(f, "model")), fmt(pv), fmt(get(f, "persistence")),
                          fmt(get(f, "persistence_fit")),
                          fmt(get(f, "diff"), signed=True),
                          DASH if ci is None else f"[{ci[0]:+.2f}, {ci[1]:+.2f}]",
                          DASH if pci is None else f"[{pci[0]:+.2f}, {pci[1]:+.2f}]"])
    if srows:
        lines += ["### Held-out Δ=4 forecast across scale (cfg1)", ""]
        lines += table(["arm", "scenes", "model R²", "paper", "persistence R²", "fitted persistence R²",
                        "model − persistence",
                        "95 % CI (scene bootstrap)", "paper CI"], srows) + [""]
    return lines


def joint_table(results: dict) -> list[str]:
    joint = run_name(results, "joint", results["config"]["joint_variant"])
    rows = []
    for store, label in (("kuka", "cfg7 (KUKA)"), ("flexiv", "cfg1 (Flexiv)")):
        spec = metrics(results, run_name(results, store, results["config"]["joint_variant"]), store)
        j = metrics(results, joint, store)
        pj = P.REAL_JOINT["kuka_force_ood"] if store == "kuka" else {}
        rows.append([label, pair(pos(spec, "ood"), pos(j, "ood")), pair(auc(spec, "ood"), auc(j, "ood")),
                     pair(force(spec, "ood"), force(j, "ood")),
                     DASH if not pj else pair(pj["specialist"], pj["joint"])])
    head = ["evaluated on", "position OOD (specialist / joint)", "AUC OOD (specialist / joint)",
            "force OOD (specialist / joint)", "paper force OOD (specialist / joint)"]
    return (["## One model, two robots: configuration-blind " + results["config"]["joint_variant"] + " (§5)", ""]
            + table(head, rows) + [""])


def markdown(results: dict) -> str:
    exps = results["experiments"]
    synthetic = sorted(k for k, v in results.get("store_info", {}).items() if v.get("synthetic"))
    if synthetic:
        title = ("# Real-robot pipeline on SYNTHETIC RH20T-layout corpora (not RH20T data; paper §5 / App. C)"
                 if len(synthetic) == len(results["store_info"]) else
                 "# Real-robot results (paper §5 / App. C): RH20T and SYNTHETIC stores mixed")
        lines = [title, "", f"Stores {', '.join(f'`{k}`' for k in synthetic)} were converted from corpora written by "
                 "`pokeworld rh20t-synth` (PokeWorld episodes in the RH20T layout), not from robot recordings: their "
                 "numbers test the pipeline, and the paper's RH20T columns are shown only to keep the table shapes.",
                 ""]
    else:
        lines = ["# Real-robot results (RH20T, paper §5 / App. C)", ""]
    lines += ["Readouts are ridge R² from the frozen, leak-free predictor state (IID = probe-test episodes, "
              "OOD = held-out tasks); 16-step errors are decoded TCP-position errors in cm; AUC is contact-onset "
              "anticipation on steps not yet in contact. Paper columns are the paper's numbers, never ours.", ""]
    for key, info in results.get("store_info", {}).items():
        kind = " (synthetic)" if info.get("synthetic") else ""
        lines.append(f"- store `{key}`{kind}: {info.get('episodes')} episodes, splits {info.get('split_counts')}, "
                     f"onset base rate {fmt(info.get('onset_base_rate'), 4)}")
    lines.append("")
    if "kuka" in exps:
        lines += kuka_table(results)
    if "viewpoint" in exps:
        lines += viewpoint_table(results)
    if "scaling" in exps:
        lines += cfg1_table(results)
    if "kuka" in exps and "scaling" in exps:
        lines += cross_table(results)
    if results["config"]["untrained"] and ("scaling" in exps or "kuka" in exps):
        lines += untrained_table(results)
    if "scaling" in exps or "kuka" in exps:
        lines += forecast_table(results)
    if "joint" in exps:
        lines += joint_table(results)
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- figure
def scissors(results: dict, out: Path) -> Path | None:
    """Fig. "scissors": position readout, held-out Δ=4 force forecast and direct 16-step error vs scale."""
    if "scaling" not in results["experiments"]:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    c = results["config"]
    total = results.get("store_info", {}).get("flexiv", {}).get("scenes")
    frac = lambda s: 1.0 if s == 1.0 else (s / total if s > 1 and total else s)  # noqa: E731
    colors = {"V": "tab:gray", "VX": "tab:orange", "VF": "tab:green", "VFX": "tab:blue"}
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    for arm in c["arms"]:
        xs, piid, pood, fc, fp, d16, ctl = [], [], [], [], [], [], None
        for s in sorted(c["scales"], key=frac):
            st = "flexiv" if s == 1.0 else f"flexiv@{s:g}"
            m = metrics(results, run_name(results, st, arm), "flexiv")
            xs.append(frac(s))
            piid.append(pos(m, "iid"))
            pood.append(pos(m, "ood"))
            fc.append(get(m, "forecast", "4", "ood", "model"))
            fp.append(get(m, "forecast", "4", "ood", "persistence"))
            d16.append(pred(m, "direct16"))
        if c["compute_control"]:
            ctl = metrics(results, run_name(results, "flexiv", arm, c["compute_control"]), "flexiv")
        col = colors.get(arm)
        nan = lambda v: [float("nan") if x is None else x for x in v]  # noqa: E731
        axes[0].plot(xs, nan(piid), "o-", color=col, label=arm)
        axes[0].plot(xs, nan(pood), "o--", color=col)
        axes[1].plot(xs, nan(fc), "o-", color=col, label=arm)
        axes[2].plot(xs, nan(d16), "o-", color=col, label=arm)
        if ctl is not None:
            for ax, v in ((axes[0], pos(ctl, "iid")), (axes[1], get(ctl, "forecast", "4", "ood", "model")),
                          (axes[2], pred(ctl, "direct16"))):
                if v is not None:
                    ax.plot([1.0], [v], "x", color=col, ms=9)
        pv = P.REAL_CFG1.get(arm, {})
        px = [n / P.REAL_CFG1_SCENES for n in sorted(pv)]
        axes[0].plot(px, [pv[n]["position"][0] for n in sorted(pv)], "s", mfc="none", color=col, alpha=0.6)
        axes[2].plot(px, [pv[n]["pred16"] for n in sorted(pv)], "s", mfc="none", color=col, alpha=0.6)
        fv = P.REAL_FORECAST_SCALING.get(arm)
        if fv:
            axes[1].plot([n / P.REAL_CFG1_SCENES for n in sorted(fv)], [fv[n] for n in sorted(fv)], "s",
                         mfc="none", color=col, alpha=0.6)
        if arm == c["arms"][-1] and fp and fp[-1] is not None:
            axes[1].plot(xs, nan(fp), ":", color="k", label="persistence")
    statics = [pred(metrics(results, name, "flexiv"), "static16") for name, r in results["runs"].items()
               if r["store"] == "flexiv"]
    statics = [s for s in statics if s is not None]
    if statics:
        axes[2].axhline(statics[0], color="k", ls=":", label="static")
    axes[0].set(title="position readout (solid IID, dashed OOD)", ylabel="R²")
    axes[1].set(title="held-out force forecast, Δ = 0.4 s", ylabel="R²")
    axes[2].set(title="direct 16-step error", ylabel="cm")
    for ax in axes:
        ax.set_xlabel("share of the corpus's scenes in training")
        ax.legend(fontsize=7)
    synthetic = " — SYNTHETIC corpus, not RH20T" if results.get("store_info", {}).get("flexiv", {}).get("synthetic") else ""
    fig.suptitle("Four-arm factorial across scale (cfg1). Filled: ours; hollow squares: paper; ×: compute control"
                 + synthetic, fontsize=9)
    fig.tight_layout()
    return save_figure_as(fig, [out / "scissors.png"], dpi=120)[0]


def write_all(out: Path, results: dict) -> list[Path]:
    """Write results.md and, when the scaling experiment ran, scissors.png; returns the paths written.
    A scissors.png left by an earlier scaling run in ``out`` is removed rather than reported as current."""
    save_text(out / "results.md", markdown(results))
    written = [out / "results.md"]
    fig = scissors(results, out)
    if fig is not None:
        written.append(fig)
    else:
        remove_own_file(out / "scissors.png")
    return written
