"""``pokeworld export RUN --out DIR``: a finished run as a self-contained model folder in the model-hub layout.

The folder (:mod:`pokeworld.model_folder` owns its format) holds the model card ``README.md`` (YAML front matter
with the library, tags, licence, dataset and the measured metrics; the text says what the model is, how to use
it and the exact command that reproduces it), ``config.json`` (architecture and training config) and the weights
as ``model.safetensors``: no pickle, so anyone can load them without running code. ``probe``, ``plan`` and the
protocol read the folder as they read the run.

Everything is checked and made before the first write: the run (finished, its weights finite and fitting their
kwargs), its ``measure.json`` (:func:`pokeworld.evaluate.measure_record.read_readout`), and ``--out``, which must be
new, empty or an earlier export (:data:`pokeworld.model_folder.EXPORTED_FOLDER`): a training run or any other
folder is refused, nothing in it changed. The card is written last, after the weights and the config, and an
earlier card is removed first, so a folder whose export stopped half-way has no card and no reader takes it.
"""

from __future__ import annotations

import json
import os
import shlex
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

import tyro

import torch

from . import __version__, checkpoint
from .config import to_dict
from .errors import ConfigError
from .evaluate.measure_record import read_readout
from .io import (
    check_outputs,
    check_owned_dir,
    parse_json,
    read_regular_bytes,
    remove_own_file,
    save_bytes,
    save_text,
    write_json,
)
from .model_folder import CARD, CONFIG, EXPORTED_FOLDER, FORMAT, WEIGHTS, folder_config, read_weights
from .models.xjepa import VARIANTS
from .preflight import finished_run
from .rundir import model_from_checkpoint, read_metrics

LICENSE = "mit"
"""The licence of the weights: the repository's own (MIT)."""
#: Training-config fields that say where and how a run was executed, not what it learned: left out of the
#: reproducing command (the store and the output folder are its DIR and RUN).
MACHINE_FIELDS = ("data", "out", "data_path", "data_sha256", "deadline", "stop_at", "device", "threads",
                  "progress", "tensorboard")
#: The measurement's held-out ridge R² (contact windows) and prediction errors the card reports, with their names.
CARD_METRICS = {"log_k": "ridge R² log k (contact windows)", "log_m": "ridge R² log m (contact windows)",
                "gamma": "ridge R² γ (contact windows)", "object_pos": "ridge R² object position (contact windows)",
                "object_vel": "ridge R² object velocity (contact windows)"}
CARD_ERRORS = {"direct16": "Δ=16 direct-head position error", "rollout16": "Δ=16 rollout position error",
               "static16": "Δ=16 static-prediction error (baseline)"}


@dataclass
class ExportConfig:
    """Export one finished run as a model folder (model card, config.json, model.safetensors)."""

    run_dir: str = "runs/xjepa"
    """The finished run to export (what `pokeworld train` wrote; its measure.json, if any, gives the card's
    metrics: run `pokeworld probe RUN` first to have them)."""
    out: str = "models/xjepa"
    """The model folder to write: README.md, config.json, model.safetensors."""
    data_command: str = ""
    """How the training store was made, quoted in the card's reproduce section (e.g. `pokeworld generate
    --preset cpu DIR`); default: the store is named by its path and content hash only."""
    dtype: str = "float32"
    """float32, or bfloat16: float32 tensors of at least 4,096 elements stored in bfloat16 (half the size; exact for
    weights that came back from a GPU lease, which travel so rounded; biases, norms and statistics stay float32)."""
    provenance: Annotated[dict, tyro.conf.Suppress] = field(default_factory=dict)
    """Where the run was trained (lease, device, date, commit, environment, preset, corpus hash; a released model's,
    from ``scripts/land_lease.py``): kept in config.json's ``source`` and said on the card. With it the exported
    config names no machine's paths (the store is DIR, the run its name) and the run's measure.json and metrics
    travel with the folder (measure.json, training_metrics.jsonl)."""

    def __post_init__(self) -> None:
        if self.dtype not in ("float32", "bfloat16"):
            raise ConfigError(f"--dtype must be float32 or bfloat16, got {self.dtype!r}")


def exported_model(run_dir: Path) -> tuple[dict, dict[str, torch.Tensor], int]:
    """The model kwargs, the float weights and the step of a finished run (``final.pt``) or of an exported folder,
    checked as every reader checks them (:func:`pokeworld.rundir.model_from_checkpoint`)."""
    exported = folder_config(run_dir)
    if exported is not None:
        ck = {"model": read_weights(run_dir), "model_kwargs": exported["model_kwargs"], "step": exported["step"]}
        path = run_dir / WEIGHTS
    else:
        path = run_dir / "final.pt"
        ck = checkpoint.load(path)
    model = model_from_checkpoint(ck, path)  # refuses kwargs or shapes that do not fit before anything is written
    state = {k: v.detach().contiguous() for k, v in model.state_dict().items()}
    step = ck.get("step")
    return dict(ck["model_kwargs"]), state, step if isinstance(step, int) and not isinstance(step, bool) else 0


def reproduce_command(train_cfg: dict) -> str:
    """The ``pokeworld train`` line that trains this run again on its store: the training preset its sizes match
    and every field that differs from that preset, except where it ran (:data:`MACHINE_FIELDS`)."""
    from .evaluate.measure import training_preset
    from .train.config import make_config as train_config

    preset = training_preset(train_cfg) or "paper"
    base = to_dict(train_config(preset))
    words = ["pokeworld", "train", "--preset", preset]
    for name in sorted(base):
        if name in MACHINE_FIELDS or name not in train_cfg or (train_cfg[name] == base[name]
                                                               and name not in ("variant", "seed")):
            continue
        value, flag = train_cfg[name], "--" + name.replace("_", "-")
        if isinstance(value, bool):
            words.append(flag if value else "--no-" + name.replace("_", "-"))
        elif isinstance(value, list):
            words += [flag, *map(str, value)]
        else:
            words += [flag, str(value)]
    return shlex.join(words + ["--data", "DIR", "--out", "RUN"])


def front_matter(train_cfg: dict, measured: dict | None, name: str) -> str:
    """The card's YAML metadata; every value is written in YAML's flow style (JSON), which hubs and YAML
    parsers read alike."""
    variant = str(train_cfg.get("variant", "?"))
    meta: dict[str, Any] = {
        "library_name": "pokeworld", "license": LICENSE,
        "tags": ["pokeworld", "x-jepa", "world-model", "jepa", "sigreg", "physics", "identifiability",
                 f"variant-{variant}", "safetensors"],
        "datasets": [f"pokeworld-{Path(str(train_cfg.get('data') or 'corpus')).name}" if train_cfg.get("data") != "DIR"
                     else f"pokeworld-{str(train_cfg.get('data_sha256'))[:12]}"],
        "dataset_sha256": train_cfg.get("data_sha256"),
    }
    if measured:
        metrics = [{"type": "r2", "name": label, "value": round(float(v), 4)}
                   for k, label in CARD_METRICS.items() if (v := measured["ridge"].get(k)) is not None]
        metrics += [{"type": "position_error", "name": label, "value": round(float(v), 4)}
                    for k, label in CARD_ERRORS.items() if (v := measured["prediction"].get(k)) is not None]
        meta["model-index"] = [{"name": name, "results": [{
            "task": {"type": "representation-probing", "name": "physical-parameter probes on the frozen state"},
            "dataset": {"type": "pokeworld", "name": "PokeWorld probe-test episodes",
                        "revision": str(measured.get("data_sha256", ""))[:12]},
            "metrics": metrics}]}]
    return "---\n" + "".join(f"{k}: {json.dumps(v, ensure_ascii=False)}\n" for k, v in meta.items()) + "---\n"


def measured_metrics(run_dir: Path) -> dict | None:
    """The probe's held-out ridge R² (contact windows) and prediction errors from ``run_dir/measure.json``, every
    field checked (:func:`~pokeworld.evaluate.measure_record.read_readout`); None when the run was not measured."""
    res = read_readout(run_dir / "measure.json")
    if not res:
        return None
    return {"ridge": res["ridge"].get("contact", {}), "prediction": res["prediction"],
            "data_sha256": res["data_sha256"]}


def card_text(train_cfg: dict, measured: dict | None, cfg: ExportConfig, step: int, note: str) -> str:
    """The model card: front matter, then what the model is, how to use it, how it was trained and measured, and
    the commands that reproduce it."""
    variant = str(train_cfg.get("variant", "?"))
    inputs, targets = VARIANTS.get(variant, (("?",), ("?",)))
    name = f"pokeworld X-JEPA {variant} (seed {train_cfg.get('seed', '?')})"
    lines = [front_matter(train_cfg, measured, name), f"# {name}", "",
             f"An X-JEPA action-conditioned latent world model trained on PokeWorld with pokeworld (the open-source "
             f"toolkit implementing *What Can Latent World Models Know? Physical Parameter Identifiability in "
             f"Multimodal Predictive Representations*): inputs {' + '.join(inputs)}, targets {' + '.join(targets)}. "
             "The card's metrics say how much of the hidden mass, drag and stiffness a linear probe reads from its "
             "frozen state.", "",
             "## Use", "", "MODEL is this folder, DIR a PokeWorld store (`pokeworld generate`).", "", "```bash",
             "pokeworld probe MODEL --data DIR      # probes and prediction errors -> MODEL/measure-<DIR's name>.json",
             "pokeworld plan OUT --runs MODEL       # CEM push-to-goal with this model", "```", "",
             "```python", "from pokeworld.rundir import load_model",
             "model = load_model('MODEL')           # the weights are safetensors: loading runs no code",
             "from pokeworld.protocol import certify_model",
             "certify_model('MODEL', data='DIR', out='OUT')   # the certificate-gated protocol", "```", "",
             "## Training", "",
             f"- variant {variant}, {step} steps ({train_cfg.get('steps')} configured), seed {train_cfg.get('seed')}",
             f"- store: content sha256 `{train_cfg.get('data_sha256')}` (trained from `{train_cfg.get('data')}`)",
             *source_lines(cfg.provenance, cfg.dtype)]
    rows = read_metrics(cfg.run_dir) if (Path(cfg.run_dir) / "metrics.jsonl").exists() else []
    if rows and isinstance(rows[-1].get("loss"), (int, float)):
        lines.append(f"- final training loss {rows[-1]['loss']:.4g} at step {rows[-1]['step']}")
    if note:
        lines.append(f"- {note}")
    lines += ["", "## Reproduce", "", "```bash"]
    if cfg.data_command:
        lines += ["# the training store, DIR:", cfg.data_command]
    lines += [reproduce_command(train_cfg), "pokeworld probe RUN --data DIR", "```", ""]
    lines += metrics_lines(measured)
    how = (f"`pokeworld export {cfg.run_dir} --out {cfg.out}`" if not cfg.provenance else
           f"from the weights lease `{cfg.provenance.get('lease')}` returned: `python scripts/land_lease.py`, its "
           "record in docs/results/leases/")
    lines += ["", f"Licence: {LICENSE.upper()}. Exported with pokeworld {__version__} ({how})."]
    return "\n".join(lines) + "\n"


def source_lines(source: dict, dtype: str) -> list[str]:
    """The card's lines on where the run was trained (a released model's provenance) and how its weights are
    stored."""
    lines = []
    if source:
        lines.append(f"- trained on {source.get('device')} ({source.get('date')}, torch {source.get('torch')}, "
                     f"commit {source.get('commit')}), GPU lease `{source.get('lease')}`, run `{source.get('run')}`")
        lines.append(f"- environment `{source.get('environment')}` (PokeWorld's default: the authors' released "
                     f"simulator), preset `{source.get('preset')}` (the released reference's objective and model); "
                     f"corpus sha256 `{source.get('corpus_sha256')}`")
        if source.get("returned"):
            lines.append(f"- weights: {source['returned']}")
        lines.append("- the numbers under Measured are the GPU's own `pokeworld probe` of the float32 weights after "
                     "training (the paper map's measurement: ridge probes on every window of the corpus's probe "
                     "splits; measure.json here); on a CPU, `pokeworld probe MODEL --data DIR --preset paper "
                     "--no-mlp --no-untrained` recomputes them from these weights (ridge within 0.001)")
    if dtype == "bfloat16":
        lines.append(f"- model.safetensors: float32 tensors of at least {BF16_MIN_ELEMENTS} elements in bfloat16, "
                     "the rest float32; loaded into the float32 model as they are")
    return lines


def metrics_lines(measured: dict | None) -> list[str]:
    if not measured:
        return ["## Measured", "", "Not measured: run `pokeworld probe RUN` before exporting to have the card carry "
                "the probes' numbers."]
    lines = ["## Measured (`pokeworld probe`, held-out probe-test episodes)", "", "| metric | value |", "|---|---|"]
    lines += [f"| {label} | {measured['ridge'][k]:+.3f} |" for k, label in CARD_METRICS.items()
              if measured["ridge"].get(k) is not None]
    lines += [f"| {label} | {measured['prediction'][k]:.4f} |" for k, label in CARD_ERRORS.items()
              if k in measured["prediction"]]
    return lines + ["", f"On the store with content sha256 `{measured.get('data_sha256')}`."]


BF16_MIN_ELEMENTS = 4096
"""``--dtype bfloat16`` stores float32 tensors of at least this many elements in bfloat16: the rule a GPU lease's
return rounds by (``pokeworld.remote.pack``), so its weights are stored exactly."""
RELEASED_FILES = {"measure.json": "measure.json", "metrics.jsonl": "training_metrics.jsonl"}
"""A released model's measurement and training log, from the run's file to the folder's."""


MACHINE_PATH_KEYS = {"data": "DIR", "data_path": "DIR", "run_dir": "MODEL", "out": "MODEL"}
"""Keys of a measure.json whose values are paths of the machine that measured: placeholders in a released model."""


def without_paths(value: Any) -> Any:
    """``value`` (a parsed measure.json) with every :data:`MACHINE_PATH_KEYS` string replaced by its placeholder."""
    if isinstance(value, dict):
        return {k: (MACHINE_PATH_KEYS[k] if k in MACHINE_PATH_KEYS and isinstance(v, str) and v else without_paths(v))
                for k, v in value.items()}
    if isinstance(value, list):
        return [without_paths(v) for v in value]
    return value


def released_files(run_dir: Path) -> dict[str, bytes]:
    """The run's measure.json (its machine's paths as placeholders) and metrics a released model carries (folder
    name -> bytes), those the run has."""
    out = {dest: read_regular_bytes(run_dir / src, f"a run's {src}", 64 << 20)
           for src, dest in RELEASED_FILES.items() if (run_dir / src).is_file()}
    if "measure.json" in out:
        measured = parse_json(out["measure.json"], run_dir / "measure.json", "a run's measure.json",
                              "measure the run again (pokeworld probe)")
        out["measure.json"] = (json.dumps(without_paths(measured), indent=2) + "\n").encode()
    return out


#: Files only a training run's folder holds.
TRAINING_FILES = ("final.pt", "ckpt.pt", "DONE", "metrics.jsonl")


def check_destination(out: Path) -> None:
    """ConfigError unless ``out`` is new, an empty folder or an earlier export (:data:`EXPORTED_FOLDER`): a training
    run's folder, a user's files or a link there are refused whole; nothing is created."""
    if os.path.islink(out) or (os.path.lexists(out) and not out.is_dir()):
        raise ConfigError(f"--out {out} is a link or a file, not a folder; name a new folder for the export")
    if out.is_dir() and any(out.iterdir()):
        if any(os.path.lexists(out / n) for n in TRAINING_FILES) or (
                os.path.lexists(out / CONFIG) and folder_config(out) is None):
            raise ConfigError(f"--out {out} holds a training run; an export never replaces one (the run would then "
                              "load as the exported model under its own name): name a new folder for the export")
        check_owned_dir(out, EXPORTED_FOLDER)


def run(cfg: ExportConfig) -> Path:
    """Write ``cfg.out``: the model card, config.json and model.safetensors of the finished run ``cfg.run_dir``.
    Refused with one line before anything is written: a run that has not finished, weights that do not fit their
    declared model or are not finite, a damaged measure.json, an output folder that is not an earlier export."""
    from safetensors.torch import save

    run_dir, out = Path(cfg.run_dir), Path(cfg.out)
    if out.resolve() == run_dir.resolve():
        raise ConfigError(f"--out {out} is the run folder itself; name a new folder for the export")
    train_cfg = finished_run(run_dir)
    kwargs, state, step = exported_model(run_dir)
    measured = measured_metrics(run_dir)
    done = run_dir / "DONE"
    note = read_regular_bytes(done, "a DONE marker", 4096).decode(errors="replace").strip()[:300] \
        if done.is_file() else ""
    note = "" if (note.startswith("finished") and "(" not in note) or cfg.provenance else note
    # every byte made before the first write, so nothing is written unless all of it is
    if cfg.dtype == "bfloat16":
        state = {k: v.to(torch.bfloat16) if v.dtype == torch.float32 and v.numel() >= BF16_MIN_ELEMENTS else v
                 for k, v in state.items()}
    weights = save(state, metadata={"format": FORMAT, "variant": str(train_cfg.get("variant"))})
    if cfg.provenance:  # a released model: no machine's paths; the store is DIR, the run its name
        train_cfg = {**train_cfg, **{k: "DIR" for k in ("data", "data_path") if k in train_cfg},
                     "out": str(cfg.provenance.get("run", "RUN"))}
    config = {"format": FORMAT, "library_name": "pokeworld", "model_type": "xjepa", "model_kwargs": kwargs,
              "train_config": train_cfg, "step": step, "pokeworld": __version__,
              **({"source": dict(cfg.provenance)} if cfg.provenance else {})}
    card = card_text(train_cfg, measured, cfg, step, note)
    extra = released_files(run_dir) if cfg.provenance else {}
    check_destination(out)
    check_outputs(out, CARD, CONFIG, WEIGHTS, *extra)
    remove_own_file(out / CARD)  # an earlier export's card: the folder is incomplete until the new one is written
    save_bytes(out / WEIGHTS, weights)
    write_json(out / CONFIG, config)
    for name, data in extra.items():
        save_bytes(out / name, data)
    save_text(out / CARD, card)  # last: the card says the export is complete
    print(f"[export] {run_dir} ({train_cfg.get('variant')}, {step} steps, "
          f"{'measured' if measured else 'not measured'}): wrote {CARD}, {CONFIG}, {WEIGHTS} → {out}")
    return out


__all__ = ["ExportConfig", "run", "reproduce_command", "card_text", "front_matter", "source_lines",
           "measured_metrics", "exported_model", "BF16_MIN_ELEMENTS", "RELEASED_FILES", "released_files"]
