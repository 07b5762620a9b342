"""pokeworld command line: one subcommand per job, each a thin wrapper over run(cfg).

Usage: pokeworld <command> [POSITIONAL] [--preset tiny|cpu|paper] [--field value ...].
--preset picks the named preset the dataclass defaults are layered with;
every other flag is parsed by tyro against that command's config dataclass
(pokeworld <command> --help lists them with their docstrings).
The defaults chain: generate writes data/pokeworld, which stats, certify and train read;
train writes runs/xjepa, which probe and plan read.
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib
import importlib.util
import re
import sys
import time
import typing
from dataclasses import dataclass
from pathlib import Path

from .config import parsing_command_line
from .errors import ConfigError, PokeworldError
from .io import read_json, read_jsonl


@dataclass(frozen=True)
class Command:
    module: str
    config: str
    help: str
    positional: str | None = None
    """The config field a bare argument fills (every one has a default, so it is optional)."""
    make: str = "make_config"
    """The module's ``make(preset) -> config``; empty for a config without presets (its defaults)."""
    runner: str = "run"
    cost: str = ""
    """What the command costs when that does not follow from the preset's per-model cost (the demo)."""
    metavar: str = ""
    """How the positional is shown in the usage line and the README (default: :data:`METAVARS`)."""
    config_module: str = ""
    """Where the config and its ``make`` live when not in ``module``: a module that imports without the command's
    extra, so ``--help`` works (and names the extra) where the extra is missing."""
    extra: str = ""
    """The optional dependency group the command needs (named in its help when it is not installed)."""
    own_preset: str = ""
    """A function of the config module naming the preset a parsed config's input was made with (``probe``: the
    run's training preset); without --preset the command then uses that one instead of ``cpu``."""


#: How a positional argument is named in usage lines: what it is, not the config field it fills.
METAVARS = {"data": "DIR", "out": "OUT", "plan.out": "OUT", "run_dir": "RUN", "root": "ROOT", "store": "DIR",
            "source": "PATH"}


COMMANDS: dict[str, Command] = {
    "generate": Command("pokeworld.sim.generate", "GenerateConfig", "simulate a PokeWorld corpus", "out",
                        metavar="DIR"),
    "stats": Command("pokeworld.sim.stats", "StatsConfig", "a corpus's observable statistics beside the paper's",
                     "data"),
    "certify": Command("pokeworld.certify", "CertifyConfig", "recoverability certificates for a corpus", "data"),
    "certify-curve": Command("pokeworld.certificate_curve", "CurveConfig",
                             "certificate R² against certificate-fit episodes (where each estimator plateaus)", "data"),
    "train": Command("pokeworld.train", "TrainConfig", "train one X-JEPA variant"),
    "train-stacked": Command("pokeworld.train.stacked", "StackedConfig",
                             "train a grid of runs (variants × seeds × λ) stacked in one process",
                             runner="run_config"),
    "probe": Command("pokeworld.evaluate.measure", "MeasureConfig", "probe and evaluate one trained run", "run_dir",
                     own_preset="run_preset"),
    "map": Command("pokeworld.experiments", "MapConfig", "the identifiability map end to end", "out"),
    "demo": Command("pokeworld.experiments", "MapConfig", "small map on CPU in minutes", "out",
                    make="make_demo_config",
                    cost="≈ 8 min on 2 CPU cores: 2,400 episodes, four 2,200-step models of train's "
                         "'demo' preset, demo certificates"),
    "export": Command("pokeworld.export", "ExportConfig",
                      "a finished run as a model folder: model card, config.json, model.safetensors", "run_dir",
                      make=""),
    "pairs": Command("pokeworld.sim.pairs", "PairsConfig", "matched-pairs figure", "out"),
    "forecast-dependence": Command("pokeworld.evaluate.dependence_runs", "DependenceRunsConfig",
                                   "slope ratio S of trained runs' forecasts per parameter, beside their readout",
                                   "out"),
    "plan": Command("pokeworld.plan", "PlanConfig", "CEM push-to-goal with trained runs", "out"),
    "rh20t-convert": Command("pokeworld.real.rh20t", "ConvertConfig", "convert RH20T scenes to a store", "root"),
    "rh20t-synth": Command("pokeworld.real.synthetic", "SynthConfig",
                           "write a synthetic RH20T-layout corpus with known force (and its truth)", "root"),
    "real": Command("pokeworld.real.experiment", "RealConfig", "real-robot experiments over converted RH20T stores",
                    "out"),
    "real-eval": Command("pokeworld.real.evaluate", "RealEvalConfig", "real-robot metrics of one trained run",
                         "run_dir"),
    # the stable-worldmodel bridge (the swm extra; docs/stable_worldmodel.md)
    "swm-collect": Command("pokeworld.swm.env", "CollectConfig",
                           "record PokeWorld episodes with a stable-worldmodel policy through swm.World", make="",
                           extra="swm"),
    "swm-export": Command("pokeworld.swm.dataset", "ExportConfig",
                          "export a store to stable-worldmodel's HDF5 format (touch, labels, parameters as columns)",
                          "store", make="", runner="run_export", extra="swm"),
    "swm-import": Command("pokeworld.swm.dataset", "ImportConfig",
                          "import a stable-worldmodel PokeWorld dataset (HDF5 or Lance) into a store", "source",
                          make="", runner="run_import", extra="swm"),
    "swm-certify-lewm": Command("pokeworld.swm.lewm", "LeWMConfig",
                                "train stable-worldmodel's LeWM on a store and certify it (beside X-JEPA runs)",
                                "data", config_module="pokeworld.swm.lewm_config", extra="swm"),
    "swm-plan": Command("pokeworld.swm.costable", "SwmPlanConfig",
                        "push-to-goal with stable-worldmodel's CEM / iCEM / MPPI on X-JEPA costs, beside our planner",
                        "plan.out", extra="swm"),
    "swm-certify": Command("pokeworld.swm.certify_env", "SwmCertifyConfig",
                           "certify an swm environment's physical factors, then what a LeWM knows of them", "env",
                           extra="swm"),
    "swm-targets": Command("pokeworld.swm.targets_table", "TargetsConfig",
                           "swm-certify factorial records of several environments side by side: which role of the "
                           "state (input or target) puts each certified factor in the latent"),
}

#: What ``--preset`` costs, shown by ``pokeworld --help`` and each command's ``--help`` (timings:
#: docs/model.md "Benchmark"; the same numbers as the comment on ``pokeworld.train.PRESETS``).
PRESET_COSTS: dict[str, str] = {
    "tiny": "seconds; smoke runs and the unit tests (too small for meaningful numbers)",
    "cpu": ("2 CPU cores; 32-px sizes with the released reference's loss weighting; ≈ 0.26 s/step on one core, "
            "≈ 20 min per 4,000-step model with two side by side (the default)"),
    "paper": ("GPU; the paper's sizes with the released reference's objective and model; timed with the first "
              "model: on one H100 0.041 s/step eager (fast path) ≈ 14 min per 20k-step model, "
              "0.030 compiled in the default mode; on an H200 0.0104 with CUDA graphs (the default on CUDA); "
              "stacked, 0.027 s per model-step for six eager models in one process"),
    "demo": ("train only: the cpu model with 64-wide proprio/touch encoders at batch 8, 2,200 steps, "
             "≈ 2.7 min per model with two side by side (what `pokeworld demo` trains)"),
    "cpu_first": "train only: the cpu model with the first objective (reproduces cpu records made before it changed)",
    "demo_first": "train only: the demo model with the first objective (reproduces earlier demo records)",
}


#: The presets a usage line names when the command's module does not list its own.
USUAL_PRESETS = ("tiny", "cpu", "paper")


def command_prog(name: str, presets=USUAL_PRESETS) -> str:
    """The head of a command's usage line: the command, its positional argument, and ``--preset`` with the names
    of its ``presets`` where it has presets (tyro's own usage line shows neither, as both are taken out of argv
    before tyro parses it)."""
    cmd = COMMANDS[name]
    head = f"pokeworld {name}"
    if cmd.positional:
        head += f" [{cmd.metavar or METAVARS.get(cmd.positional, cmd.positional.upper())}]"
    return head + (f" [--preset {'|'.join(presets)}]" if cmd.make else "")


def module_presets(config_mod) -> tuple[str, ...]:
    """The preset names a command's config module defines (its ``PRESETS``), in the order of :data:`PRESET_COSTS`
    (train also has ``demo``); :data:`USUAL_PRESETS` for a module without that table."""
    names = getattr(config_mod, "PRESETS", None)
    if not isinstance(names, dict):
        return USUAL_PRESETS
    return tuple(sorted(names, key=lambda p: (list(PRESET_COSTS).index(p) if p in PRESET_COSTS else len(PRESET_COSTS),
                                                p)))


#: reStructuredText a docstring may hold, and what a terminal shows instead: a role's target (the last dotted
#: part after ``~``) and a literal's text.
RST_ROLE = re.compile(r":(?:[a-z]+:)+`([^`]+)`")
RST_LITERAL = re.compile(r"``([^`]+)``")


#: A line break inside a paragraph (not a blank line), with the next line's indentation.
SOURCE_BREAK = re.compile(r"(?<!\n)[ \t]*\n(?!\s*\n)[ \t]*")


def plain_text(text: str) -> str:
    """``text`` with its reStructuredText roles and literals replaced by their plain words, and its paragraphs as
    one line each: the help rewraps them to the terminal, where the source's line breaks would fall mid-line."""
    text = RST_ROLE.sub(lambda m: m[1].rsplit(".", 1)[-1] if m[1].startswith("~") else m[1], text)
    return SOURCE_BREAK.sub(" ", RST_LITERAL.sub(r"\1", text))


def plain_help_registry(positional: tuple[type, str, str] | None = None):
    """A tyro registry that hands tyro every dataclass field's help as :func:`plain_text`.

    The field docstrings are written for Sphinx and the source; the terminal should show words, not markup. The
    rule asks tyro's own rules for the spec (re-entering the registry, where it steps aside) and rewrites only the
    help text. ``positional`` (the command's config class, the field its bare word fills, and the word's name in
    the usage line) adds to that field's help that the two are one argument.
    """
    from tyro.constructors import ConstructorRegistry, StructConstructorSpec

    registry = ConstructorRegistry()
    resolving: list[type] = []

    def plain(helptext):
        if callable(helptext):  # tyro reads docstrings lazily; stay lazy
            return lambda: plain(helptext())
        return plain_text(helptext) if helptext else helptext

    advanced_help: dict[type, dict] = {}  # the "advanced" dataclasses made below -> their fields' help

    @registry.struct_rule
    def plain_help(info):
        if resolving or not dataclasses.is_dataclass(info.type):
            return None
        resolving.append(info.type)
        try:
            spec = ConstructorRegistry.get_struct_spec(info)
        finally:
            resolving.pop()
        if not isinstance(spec, StructConstructorSpec):
            return spec
        helps = advanced_help.get(info.type, {})  # made classes have no source for tyro to read docstrings from
        fields = tuple(dataclasses.replace(f, helptext=helps.get(f.name) or plain(f.helptext)) for f in spec.fields)
        if positional is not None and info.type is positional[0]:
            fields = tuple(dataclasses.replace(f, helptext=with_note(f.helptext, f"The bare {positional[2]} of the "
                                                                     "usage line is this option: give it either way, "
                                                                     "once."))
                           if f.name == positional[1] else f for f in fields)
        common = COMMON_OPTIONS.get(info.type.__name__)
        if common:
            return advanced_group(spec.instantiate, fields, common, advanced_help)
        return dataclasses.replace(spec, fields=fields)

    return registry


def with_note(helptext, note: str):
    """``helptext`` (a string, or tyro's lazy callable giving one) with ``note`` after it."""
    if callable(helptext):
        return lambda: with_note(helptext(), note)
    return f"{helptext} {note}" if helptext else note


#: Per config class: the options most runs set, listed first by ``--help``; the others are listed after them under
#: "advanced options" (their flags unchanged). ``pokeworld train --help`` otherwise lists 60 options in the order of
#: the dataclass, where the model's and the loss's details come before ``--lr`` or ``--device``.
COMMON_OPTIONS: dict[str, tuple[str, ...]] = {
    "TrainConfig": ("variant", "data", "out", "seed", "steps", "stop_at", "batch_size", "lr", "objective",
                    "sigreg_weight", "device", "threads", "ckpt_every", "log_every", "tensorboard", "progress",
                    "deadline"),
}


def advanced_group(instantiate, fields, common: tuple[str, ...], advanced_help: dict[type, dict]):
    """A struct spec listing the ``common`` fields, then every other one inside a nested ``advanced`` struct whose
    flags keep their names (OmitArgPrefixes): tyro shows a nested struct as a box of its own, and the config is
    built from both parts exactly as from the flat fields."""
    import tyro
    from tyro.constructors import StructConstructorSpec, StructFieldSpec

    first = sorted((f for f in fields if f.name in common), key=lambda f: common.index(f.name))
    rest = [f for f in fields if f.name not in common]
    advanced = dataclasses.make_dataclass(
        "advanced", [(f.name, f.type, dataclasses.field(default_factory=lambda d=f.default: d)) for f in rest])
    advanced_help[advanced] = {f.name: f.helptext for f in rest}
    defaults = advanced(**{f.name: f.default for f in rest})

    def build(**kw):
        adv = kw.pop("advanced")
        return instantiate(**kw, **{f.name: getattr(adv, f.name) for f in rest})

    group = StructFieldSpec("advanced", typing.Annotated[advanced, tyro.conf.OmitArgPrefixes], defaults,
                            "Rarely changed: the model's sizes, the loss's terms and weights, and how a step runs.")
    return StructConstructorSpec(instantiate=build, fields=(*first, group))


def command_description(name: str, preset: str, own: bool = False) -> str:
    """The help's first paragraph: what the command does, the preset and (for training commands) its cost, and how
    to install the command's extra when it is missing. ``own``: no --preset was given to a command that then uses
    its input's own (:attr:`Command.own_preset`)."""
    cmd = COMMANDS[name]
    # the costs are per trained model, so only the commands that train quote them
    cost = cmd.cost or (PRESET_COSTS.get(preset) if cmd.config in ("TrainConfig", "MapConfig", "RealConfig")
                        else None)
    if own:
        text = f"{cmd.help} (preset: the run's own, tiny, cpu or paper, unless --preset names another)"
    else:
        text = f"{cmd.help} (preset {preset!r}" + (f": {cost})" if cost else ")")
    if cmd.extra and importlib.util.find_spec(EXTRA_PACKAGES[cmd.extra]) is None:
        text += (f". Needs the {cmd.extra} extra, not installed here; in an environment of its own (it moves torch "
                 f"to 2.14.1): python -m venv .venv-{cmd.extra} && .venv-{cmd.extra}/bin/pip install -e "
                 f"'.[{cmd.extra}]' (docs/stable_worldmodel.md)")
    return text


#: The package whose absence means an extra is not installed.
EXTRA_PACKAGES = {"swm": "stable_worldmodel"}


def config_module(name: str, argv: list[str]):
    """The module holding the command's config. Where it cannot be imported (an extra is missing) and help was
    asked for, the help says what the command is and why its options cannot be listed, instead of only the error."""
    cmd = COMMANDS[name]
    try:
        return importlib.import_module(cmd.config_module or cmd.module)
    except ConfigError as e:
        if "-h" not in argv and "--help" not in argv:
            raise
        print(f"usage: {command_prog(name)} [-h] [OPTIONS]\n\n{cmd.help}.\n\n"
              f"Its options are listed once its module imports, which needs: {e}")
        raise SystemExit(0) from None


def usage() -> str:
    """Top-level help: the module docstring, one line per command, the cost of each preset."""
    width = max(map(len, COMMANDS)) + 2
    lines = [__doc__.strip(), "", "commands:"]
    lines += [f"  {name:{width}s}{c.help}" for name, c in COMMANDS.items()]
    lines += ["", "presets (--preset):"]
    lines += [f"  {name:{width}s}{cost}" for name, cost in PRESET_COSTS.items()]
    return "\n".join(lines)


class LastLine:
    """A pass-through stdout that remembers the last non-empty line written, so the closing line is not printed
    when the command's own last line already names what it wrote."""

    def __init__(self, out):
        self.out, self.last, self.partial = out, "", ""

    def write(self, text: str) -> int:
        *done, self.partial = (self.partial + text).split("\n")
        self.last = next((line for line in reversed(done) if line.strip()), self.last)
        return self.out.write(text)

    def __getattr__(self, name):  # flush, isatty, encoding, ...: those of the real stream
        return getattr(self.out, name)

    @property
    def last_line(self) -> str:
        return self.partial if self.partial.strip() else self.last


#: Files written this long before the command started count as written by it (file-system timestamps are coarse).
MTIME_SLACK_S = 0.05


def written_since(path: Path, since: float) -> list[Path]:
    """``path`` itself if it is a file written since ``since``; a directory's files (not recursive) written since."""
    if path.is_file():
        return [path] if path.stat().st_mtime >= since else []
    if path.is_dir():
        return sorted(p for p in path.iterdir() if p.is_file() and p.stat().st_mtime >= since)
    return []


def train_closing(run: Path, finished_before: bool) -> str:
    """``[train] VFX: 10 steps, loss 3.60 → RUN/final.pt``, or that the run was finished already, or where it
    stopped (a deadline or ``stop_at``) and how to resume."""
    cfg = read_json(run / "config.json", "a run's config.json")
    rows = read_jsonl(run / "metrics.jsonl", "a run's metrics.jsonl")
    last = rows[-1] if rows else {}
    what = f"{cfg['variant']}: {last.get('step', 0)} steps"
    if isinstance(last.get("loss"), (int, float)):
        what += f", loss {last['loss']:.3g}"
    if finished_before:
        return f"[train] {run} was already finished ({what}); skipped → {run / 'final.pt'}"
    if (run / "DONE").exists():
        return f"[train] {what} → {run / 'final.pt'}"
    return (f"[train] {what} of {cfg['steps']}, stopped early (deadline or --stop-at); run the same command to "
            f"resume → {run / 'ckpt.pt'}")


def closing_line(name: str, cfg, result, since: float) -> str:
    """One line saying what the command wrote where, or that it found its output up to date and skipped."""
    if isinstance(result, (list, tuple)) and result and all(isinstance(r, Path) for r in result):
        shown = ", ".join(map(str, result[:4])) + (f" and {len(result) - 4} more" if len(result) > 4 else "")
        return f"[{name}] {len(result)} runs → {shown}"
    if not isinstance(result, Path):
        if name == "stats":
            return f"[{name}] wrote nothing; the statistics above are also in {Path(cfg.data) / 'manifest.json'}"
        result = Path(getattr(cfg, "out", "") or ".")
    new = [p for p in written_since(result, since) if not p.name.startswith(".")]  # not the ownership record
    if not new:
        return f"[{name}] {result} is up to date; skipped (nothing recomputed)"
    if new == [result]:
        return f"[{name}] wrote {result}"
    names = ", ".join(p.name for p in new[:8]) + (f" and {len(new) - 8} more" if len(new) > 8 else "")
    return f"[{name}] wrote {names} → {result}"


def run_and_report(name: str, cfg, runner, preset: str = "") -> None:
    """Run the command, then end with one line saying what it wrote where (or that it skipped), unless the
    command's own last line already named its output. ``preset``: the one --preset named (a config without a
    ``preset`` field does not record it)."""
    finished_before = name == "train" and (Path(cfg.out) / "DONE").exists()
    since = time.time() - MTIME_SLACK_S
    tee = LastLine(sys.stdout)
    with contextlib.redirect_stdout(tee):
        result = runner(cfg)
    if name == "train":
        print(train_closing(Path(result), finished_before))
        return
    named = isinstance(result, Path) and str(result) in tee.last_line
    noted = name in SMOKE_NOTE_COMMANDS and (getattr(cfg, "preset", "") or preset) == "tiny"
    if noted:
        print(CERTIFY_SMOKE_NOTE if name == "certify" else SMOKE_NOTE)
    if noted or not named:  # the last line still says what was written where
        print(closing_line(name, cfg, result, since))


#: Commands whose tables, at the tiny preset, show numbers a newcomer would take for results (errors in the
#: thousands, "no effect at this budget"); ``plan`` says so under its own table (plan.table_lines).
SMOKE_NOTE_COMMANDS = ("map", "certify")
SMOKE_NOTE = ("Note: the tiny preset's models are smoke-test sized, so the numbers above (prediction errors in the "
              "hundreds or thousands, no effects) test the pipeline, not the paper: run --preset cpu (or paper) for "
              "numbers worth reading.")
#: ``certify --preset tiny``: a FAIL there says the smoke-sized estimators learned nothing, not that the data lacks
#: the parameter.
CERTIFY_SMOKE_NOTE = ("Note: the tiny preset's estimators are smoke-test sized (a few epochs on a few windows), so "
                      "a FAIL above tests the pipeline, not the corpus: run --preset cpu (the default) for "
                      "certificates worth reading.")


def _flag_arity(cls, prefix: str = "") -> dict[str, int]:
    """Number of values each ``--flag`` of ``cls`` takes: 0 (bool), 1, or -1 (a tuple: until the next flag).

    Nested dataclass fields (``--policy.mode-weights``) are walked too, so their values are not
    mistaken for the positional argument.
    """
    hints = typing.get_type_hints(cls)
    out: dict[str, int] = {}
    for f in dataclasses.fields(cls):
        tp = hints.get(f.name)
        if dataclasses.is_dataclass(tp):
            for sub in {f.name, f.name.replace("_", "-")}:
                out.update(_flag_arity(tp, f"{prefix}{sub}."))
            continue
        arity = 0 if tp is bool else -1 if typing.get_origin(tp) is tuple else 1
        for name in {f.name, f.name.replace("_", "-")}:
            out[f"--{prefix}{name}"] = arity
            if arity == 0:
                out[f"--{prefix}no-{name}"] = 0
    return out


def split_args(argv: list[str], positional: str | None, arity: dict[str, int]) -> tuple[str, list[str]]:
    """Pull ``--preset X`` out of ``argv`` and turn the one bare positional into ``--<positional> value``.

    Flags consume their values by type (bool none, scalar one, tuple until the next flag), so a
    bare token that no flag consumes is the positional; after a tuple flag it cannot be told
    apart from the tuple's values, so put the positional first in that case. The positional and its flag are one
    argument: giving both is a ConfigError.
    """
    preset, rest, i = "cpu", [], 0
    while i < len(argv):
        tok = argv[i]
        if tok == "--preset" and i + 1 < len(argv):
            preset, i = argv[i + 1], i + 2
            continue
        if tok.startswith("--preset="):
            preset, i = tok.split("=", 1)[1], i + 1
            continue
        rest.append(tok)
        i += 1
    if positional is None:
        return preset, rest
    flag = f"--{positional.replace('_', '-')}"
    out, found, i = [], False, 0
    while i < len(rest):
        tok = rest[i]
        if tok.startswith("-"):
            out.append(tok)
            n = 0 if "=" in tok else arity.get(tok, 1)
            i += 1
            while i < len(rest) and (n == -1 or n > 0) and not rest[i].startswith("--"):
                out.append(rest[i])
                i += 1
                n -= 1 if n > 0 else 0
            continue
        if not found:
            bare, found = tok, True
            out += [flag, tok]
        else:
            out.append(tok)
        i += 1
    flagged = [tok.split("=", 1)[1] for tok in rest if tok.startswith(f"{flag}=")] + [
        rest[j + 1] for j, tok in enumerate(rest[:-1]) if tok == flag]
    if found and flagged:  # the bare word is the flag's value: given both ways, one would silently win
        raise ConfigError(f"{flag} given twice, as the bare word {bare!r} and as {flag} {flagged[0]!r}: they are one "
                          "argument; give it once")
    return preset, out


def preset_given(argv: list[str]) -> bool:
    """Whether ``argv`` names a preset (``--preset X`` or ``--preset=X``)."""
    return any(tok == "--preset" or tok.startswith("--preset=") for tok in argv)


def parse_config(name: str, argv: list[str]):
    """The command's config from ``argv``: the preset's defaults (the one --preset names; else, for a command with
    :attr:`Command.own_preset`, the one its input was made with; else ``cpu``) overridden by the flags."""
    import tyro

    cmd = COMMANDS[name]
    config_mod = config_module(name, argv)
    cls = getattr(config_mod, cmd.config)
    preset, rest = split_args(argv, cmd.positional, _flag_arity(cls))
    if not cmd.make and preset != "cpu":
        raise ConfigError(f"{name} has no presets; drop --preset {preset}")

    own = bool(cmd.own_preset) and not preset_given(argv)
    bare = (cls, cmd.positional, cmd.metavar or METAVARS.get(cmd.positional, cmd.positional.upper())) \
        if cmd.positional else None

    def parse(preset: str, **base):
        default = getattr(config_mod, cmd.make)(preset, **base) if cmd.make else cls()
        with parsing_command_line():  # a field out of range: one line, not the parser's help box
            return tyro.cli(cls, default=default, args=rest, prog=command_prog(name, module_presets(config_mod)),
                            registry=plain_help_registry(bare), description=command_description(name, preset, own))

    cfg = parse(preset)
    if cmd.make and getattr(cfg, "environment", None) not in (None, getattr(cls(), "environment", None)):
        # a named environment is the base the preset and the flags are layered on (pokeworld.sim.environments):
        # parsing again builds the defaults on it, and the other flags still win
        cfg = parse(preset, environment=cfg.environment)
    if own:
        # the input (probe: the run) is only known once parsed; parsing again layers the flags over its preset
        run_preset = getattr(config_mod, cmd.own_preset)(cfg)
        if run_preset != preset:
            cfg = parse(run_preset)
    return cfg


def interrupted_exit(name: str, argv: list[str], e: KeyboardInterrupt) -> int:
    """One line for a command stopped by Ctrl-C or SIGTERM, and the shell's exit status for it. Training that
    checkpointed at the step it stopped says so itself; otherwise the line adds the command that resumes."""
    import shlex

    if getattr(e, "checkpointed", False):  # train.loop.TrainingInterrupted, read without importing torch here
        print(f"[{name}] {e}", file=sys.stderr)
        return e.exit_code
    said = f"{e}; " if str(e) else ""
    again = (f"to resume, run: pokeworld {shlex.join([name, *argv])}" if name in RESUMING_COMMANDS else
             f"nothing partial is kept, so it starts over: run again: pokeworld {shlex.join([name, *argv])}")
    print(f"pokeworld {name}: interrupted: {said}{again}", file=sys.stderr)
    return 130


#: Commands whose rerun continues where an interrupted one stopped (checkpoints, finished runs skipped); the others
#: write their outputs whole at the end and start over (``generate`` simulates its corpus again from the start).
RESUMING_COMMANDS = ("train", "train-stacked", "map", "demo")


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(usage())
        return 0
    name, argv = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"pokeworld: unknown command {name!r}; choose one of {', '.join(COMMANDS)}", file=sys.stderr)
        return 2
    cmd = COMMANDS[name]
    try:
        cfg = parse_config(name, argv)
        preset = split_args(argv, None, {})[0] if preset_given(argv) else ""
        run_and_report(name, cfg, getattr(importlib.import_module(cmd.module), cmd.runner), preset)
    except PokeworldError as e:
        print(f"pokeworld {name}: error: {e}", file=sys.stderr)
        return 2
    except FloatingPointError as e:
        print(f"pokeworld {name}: training diverged: {e}", file=sys.stderr)
        return 3
    except KeyboardInterrupt as e:  # Ctrl-C or SIGTERM: where it stopped and how to resume, no traceback
        return interrupted_exit(name, argv, e)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
