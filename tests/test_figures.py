"""Every figure reads alone: titled, its data axes labelled, its legends' entries present and distinct, no text
outside the canvas; the identifiability map shows the paper's values beside ours and names its presets, and the
plan figure draws one panel per planned run (issue #52, "figures that need the docs").

Each figure is built from small synthetic inputs and caught at ``Figure.savefig`` (the figure functions save and
close their figure), then inspected through its artists."""

from __future__ import annotations

import re

import matplotlib

matplotlib.use("Agg")

import numpy as np
import pytest
from matplotlib.figure import Figure
from matplotlib.text import Text

from pokeworld.evaluate.tables import QUANTITIES
from pokeworld.published import paper as P

VARIANTS = ("V", "VF", "VX_p", "VX_t", "VX", "VFX")


# --------------------------------------------------------------------------- catching and inspecting figures
@pytest.fixture
def caught(monkeypatch):
    """The figures saved during the test (each once, whatever the number of formats it is written in)."""
    figs: list[Figure] = []
    real = Figure.savefig

    def savefig(self, *args, **kwargs):
        if self not in figs:
            figs.append(self)
        return real(self, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", savefig)
    return figs


def _renderer(fig: Figure):
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    if not isinstance(fig.canvas, FigureCanvasAgg):  # plt.close left the figure a bare canvas
        FigureCanvasAgg(fig)
    fig.canvas.draw()
    return fig.canvas.get_renderer()


def _is_colorbar(ax) -> bool:
    return ax.get_label() == "<colorbar>"


def _numeric(s: str) -> bool:
    return re.fullmatch(r"[-+−]?\d+(\.\d*)?(e[-+−]?\d+)?", s.strip()) is not None


def _tick_label_ids(fig: Figure) -> set[int]:
    ids = set()
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            for tick in (*axis.get_major_ticks(), *axis.get_minor_ticks()):
                ids |= {id(tick.label1), id(tick.label2)}
    return ids


def _texts(fig: Figure) -> list[Text]:
    """Every drawn text that is not a tick label: titles, axis labels, legends, annotations, footnotes."""
    ticks = _tick_label_ids(fig)
    return [t for t in fig.findobj(Text) if t.get_visible() and t.get_text().strip() and id(t) not in ticks]


def _inside(box, canvas, tol: float = 1.0) -> bool:
    return (box.x0 >= canvas.x0 - tol and box.y0 >= canvas.y0 - tol and box.x1 <= canvas.x1 + tol
            and box.y1 <= canvas.y1 + tol)


def _legends(fig: Figure) -> list:
    return [lg for lg in (*fig.legends, *(ax.get_legend() for ax in fig.axes)) if lg is not None]


def check_readable(fig: Figure) -> None:
    """The checks every figure must pass."""
    r = _renderer(fig)
    canvas = fig.bbox
    suptitle = fig._suptitle.get_text() if fig._suptitle is not None else ""
    for ax in fig.axes:
        if not ax.get_visible() or _is_colorbar(ax):
            continue
        assert ax.get_title() or ax.get_title("left") or suptitle, f"an axes with no title and no suptitle: {ax}"
    for ax in fig.axes:
        if not ax.get_visible() or not ax.axison:
            continue
        # an axis whose ticks are numbers needs its label; words as tick labels name themselves
        for axis in (ax.xaxis, ax.yaxis):
            words = [t.get_text() for t in axis.get_ticklabels() if t.get_visible() and t.get_text().strip()]
            if words and all(_numeric(w) for w in words):
                assert axis.get_label_text().strip(), f"numeric ticks without an axis label in {ax.get_title()!r}"
        # tick labels, titles and axis labels the axes draws: inside the canvas
        box = ax.get_tightbbox(r)
        assert _inside(box, canvas), f"axes {ax.get_title()!r} extends beyond the canvas: {box} vs {canvas}"
    for t in _texts(fig):
        box = t.get_window_extent(r)
        assert _inside(box, canvas), f"text {t.get_text()!r} is cut off: {box} vs {canvas}"
    for lg in _legends(fig):
        entries = [t.get_text() for t in lg.get_texts()]
        assert entries and all(e.strip() for e in entries), f"a legend with an empty entry: {entries}"
        assert len(entries) == len(set(entries)), f"a legend names an entry twice: {entries}"
        assert _inside(lg.get_window_extent(r), canvas), f"a legend is cut off: {entries}"


def all_text(fig: Figure) -> str:
    """Every visible text of the figure, its line breaks (wrapping) read as spaces."""
    return re.sub(r"\s+", " ", " ".join(t.get_text() for t in fig.findobj(Text) if t.get_visible()))


# --------------------------------------------------------------------------- the identifiability map
def map_results(variants=VARIANTS, seeds=(0,), preset="cpu", train_preset="", command="pokeworld map --preset cpu",
                failed=()) -> dict:
    """A results.json the map's report accepts: one factorial run per variant and seed, the certificates."""
    rng = np.random.default_rng(0)
    runs, names = {}, []
    for v in variants:
        for s in seeds:
            name = f"{v}-h1-4-16-lam0.02-standard-s{s}"
            names.append(name)
            runs[name] = {"experiment": "factorial", "corpus": "standard", "measure_corpus": "standard",
                          "train": {"variant": v, "seed": s, "horizons": [1, 4, 16], "sigreg_weight": 0.02},
                          "probes": {"ridge": {"contact": {q: float(rng.uniform(-0.05, 1)) for q in QUANTITIES}}}}
    cert = {"log_k": {"r2": 0.9, "estimator": "gru"}, "log_m": {"r2": 0.83, "estimator": "gru"},
            "gamma": {"r2": 0.83, "estimator": "drag"}}
    gate = {q: {"passed": q not in failed, "certificate": cert[q]["r2"], "estimator": cert[q]["estimator"]}
            for q in cert}
    return {"runs": runs, "experiments": {"factorial": names},
            "certificates": {"standard": {"certificate": {"contact": cert}, "gate": gate, "estimators": {}}},
            "map_config": {"preset": preset, "train_preset": train_preset, "train_steps": 0, "variants": list(variants),
                           "seeds": list(seeds)},
            "provenance": {"preset": preset, "command": command, "pokeworld": "0", "git": "x", "python": "3"}}


def test_the_map_shows_the_paper_beside_ours_and_explains_itself(tmp_path, caught):
    from pokeworld.experiments import report
    from pokeworld.experiments.factorial import FACTORIAL

    paths = report.figure(map_results(seeds=(0, 1)), tmp_path)
    assert {p.name for p in paths} == {"identifiability_map.png", "identifiability_map.pdf"}
    assert all(p.stat().st_size > 0 for p in paths)
    (fig,) = caught
    check_readable(fig)
    paper = [t.get_text() for t in fig.findobj(Text) if t.get_label() == "paper"]
    assert paper, "no artist labelled 'paper'"
    # the paper's own numbers, one per reported cell: VFX's log k and the GRU oracle's γ among them
    assert f"paper {FACTORIAL['VFX']['log_k']:.2f}" in paper
    assert any(f"paper {P.CERTIFICATES['gru']['gamma']:.2f}" in t for t in paper)
    words = all_text(fig)
    assert "preset cpu" in words and "held-out R²" in words and "ridge" in words and "contact windows" in words
    # position and velocity: certified by construction, and the figure says why
    assert sum(t.get_text() == "observed" for t in fig.findobj(Text)) == 2
    assert "observed directly" in words
    # every variant's name explained
    for v, meaning in report.VARIANT_KEY.items():
        assert f"{v} = {meaning}" in words
    assert "2 seeds" not in words  # every variant has both seeds: no per-variant count


def planted_log_k(res: dict, values: dict) -> dict:
    for run in res["runs"].values():
        run["probes"]["ridge"]["contact"]["log_k"] = values[run["train"]["variant"]]
    return res


def test_the_map_states_its_conclusion_computed_from_its_numbers(tmp_path, caught):
    from pokeworld.experiments import report

    target = planted_log_k(map_results(), {"V": 0.0, "VF": 0.02, "VX_p": 0.0, "VX_t": 0.1, "VX": 0.2, "VFX": 0.40})
    report.figure(target, tmp_path)
    title = caught[-1].axes[0].get_title()
    assert "Stiffness enters the latent only when touch is a forecasting target" in title
    assert "VFX − VF = +0.38" in title and "VF − V = +0.02" in title and "paper +0.51" in title
    none = planted_log_k(map_results(), {"V": 0.0, "VF": 0.02, "VX_p": 0.0, "VX_t": 0.0, "VX": 0.0, "VFX": 0.05})
    assert report.map_conclusion(none).startswith("At this budget touch as a target does not put stiffness")
    both = planted_log_k(map_results(), {"V": 0.0, "VF": 0.3, "VX_p": 0.0, "VX_t": 0.0, "VX": 0.0, "VFX": 0.6})
    assert "with touch as a target and as an input" in report.map_conclusion(both)
    assert report.map_conclusion(map_results(variants=("V", "VX_t"))) is None  # no VFX and VF: nothing to conclude


def test_the_certificate_column_compares_gru_oracles_and_names_the_best_apart(tmp_path, caught):
    from pokeworld.experiments import report

    res = map_results()
    res["certificates"]["standard"]["estimators"] = {"gru": {"contact": {"log_k": 0.9, "log_m": 0.83, "gamma": 0.81}},
                                                     "drag": {"contact": {"gamma": 0.83}}}
    M, _, cols, _ = report.map_matrix(res)
    assert cols[0] == "certificate" and M[2, 0] == 0.81  # γ: our GRU oracle, beside the paper's GRU oracle
    report.figure(res, tmp_path)
    fig = caught[-1]
    texts = [t.get_text() for t in fig.findobj(Text)]
    assert f"paper {P.CERTIFICATES['gru']['gamma']:.2f}\nbest: drag 0.83" in texts
    assert "certificate\n(GRU oracle)" in [t.get_text() for t in fig.axes[0].get_xticklabels()]
    check_readable(fig)
    without = map_results()  # no GRU oracle fit (the tiny preset): the best estimator, named
    assert report.map_matrix(without)[0][2, 0] == 0.83


def test_the_demo_map_names_its_training_preset_and_marks_a_failed_gate(tmp_path, caught):
    from pokeworld.experiments import report

    res = map_results(variants=("V", "VF", "VX_t", "VFX"), train_preset="demo", command="pokeworld demo",
                      failed=("log_m",))
    report.figure(res, tmp_path, stem="identifiability_map_demo")
    (fig,) = caught
    check_readable(fig)
    title = fig.axes[0].get_title()
    assert "training preset demo" in title and "pokeworld demo" in title
    words = all_text(fig)
    assert "gate ✗" in words and "no claim" in words
    assert "VX_p =" not in words  # only the variants drawn are explained


def test_the_map_counts_seeds_where_variants_differ(tmp_path, caught):
    from pokeworld.experiments import report

    res = map_results(variants=("V", "VFX"), seeds=(0, 1))
    del res["runs"]["V-h1-4-16-lam0.02-standard-s1"]
    res["experiments"]["factorial"].remove("V-h1-4-16-lam0.02-standard-s1")
    report.figure(res, tmp_path)
    (fig,) = caught
    check_readable(fig)
    ticks = [t.get_text() for t in fig.axes[0].get_xticklabels()]
    assert ticks == ["certificate", "V\n1 seed", "VFX\n2 seeds"]


# --------------------------------------------------------------------------- the plan episode figure
def planned(labels, episodes: int = 4, steps: int = 12) -> dict:
    """plan_runs's output for the figure: per controller, distances and object / finger paths."""
    rng = np.random.default_rng(1)
    goal = rng.uniform(0.3, 0.7, (episodes, 2))
    start = rng.uniform(0.2, 0.8, (episodes, 2))
    eps = {}
    for k, label in enumerate(labels):
        frac = np.linspace(0, 1, steps + 1)[None, :, None] * (0.2 + 0.35 * k)
        obj = start[:, None] + frac * (goal - start)[:, None]
        eps[label] = {"distance": np.linalg.norm(obj - goal[:, None], axis=-1), "object_path": obj,
                      "finger_path": obj + 0.03 * rng.normal(size=obj.shape)}
    return {"episodes": eps, "setup": {"goal": goal}}


def _episode_axes(fig: Figure) -> list:
    return [ax for ax in fig.axes if ax.get_xlabel() == "arena x"]


def test_one_planned_run_draws_one_panel_and_says_so(tmp_path, caught):
    from pokeworld import plan

    plan.figure(planned(["random", "xjepa"]), tmp_path, goal_radius=0.1)
    (fig,) = caught
    check_readable(fig)
    assert len(_episode_axes(fig)) == 1
    suptitle = fig._suptitle.get_text()
    assert "two" not in suptitle and "xjepa" in suptitle
    (dist,) = [ax for ax in fig.axes if ax.get_xlabel() == "control step"]
    entries = [t.get_text() for t in dist.get_legend().get_texts()]
    assert entries.count("xjepa") == 1 and any(e.startswith("random") for e in entries)
    assert (tmp_path / "plan_episode.png").exists() and (tmp_path / "plan_episode.pdf").exists()


def test_two_planned_runs_keep_the_comparison_with_long_names_inside_the_canvas(tmp_path, caught):
    from pokeworld import plan

    names = ["V-h1-4-16-lam0.02-standard-s0", "VFX-h1-4-16-lam0.02-standard-s0"]
    plan.figure(planned(["random", *names]), tmp_path, goal_radius=0.1)
    (fig,) = caught
    check_readable(fig)  # the committed plan_episode_cpu.png cut its left panel's title
    panels = _episode_axes(fig)
    assert len(panels) == 2
    assert [ax.get_title().split("\n")[0] for ax in panels] == names
    assert "two frozen latents" in fig._suptitle.get_text()


def test_the_simulator_alone_is_planned_with_its_own_scores(tmp_path, caught):
    from pokeworld import plan

    plan.figure(planned(["random", "simulator"]), tmp_path, goal_radius=0.1)
    (fig,) = caught
    check_readable(fig)
    assert len(_episode_axes(fig)) == 1
    assert "simulator's own scores" in fig._suptitle.get_text()


# --------------------------------------------------------------------------- figures owned elsewhere: checked only
def test_the_pairs_figure_reads_alone(tmp_path, caught):
    from pokeworld.sim import pairs

    pairs.run(pairs.make_config("tiny", out=str(tmp_path)))
    (fig,) = caught
    check_readable(fig)


def test_the_protocol_figure_reads_alone(tmp_path, caught):
    from pokeworld import protocol

    qs = ("log_m", "gamma", "log_k", "object_pos", "object_vel")
    result = {
        "model": {"name": "encoder", "state_dim": 8},
        "probes": {"ridge": {"contact": dict(zip(qs, (0.2, -0.5, 0.6, 0.99, 0.7)))},
                   "mlp": {"contact": dict(zip(qs, (0.3, 0.1, 0.7, 0.99, 0.8)))}},
        "untrained": {"ridge": {"contact": dict(zip(qs, (0.0, 0.0, 0.1, 0.9, 0.4)))}},
        "certificates": {"certificate": {"contact": {q: {"r2": 0.8, "estimator": "gru"} for q in qs[:3]}},
                         "estimators": {"gru": {"contact": {q: 0.8 for q in qs[:3]}}},
                         "gate": {"log_m": {"passed": True}, "gamma": {"passed": False}, "log_k": {"passed": True}}},
    }
    protocol.figure(result, tmp_path / "protocol.png")
    (fig,) = caught
    check_readable(fig)
