"""``pokeworld`` command line: one subcommand per job, each a thin wrapper over ``run(cfg)``.

Usage: ``pokeworld <command> [--preset tiny|cpu|paper] [--field value ...] [POSITIONAL]``.
``--preset`` picks the named preset the dataclass defaults are layered with;
every other flag is parsed by tyro against that command's config dataclass
(``pokeworld <command> --help`` lists them with their docstrings).
"""

from __future__ import annotations

import dataclasses
import importlib
import sys
import typing
from dataclasses import dataclass

from .errors import ConfigError, PokeworldError


@dataclass(frozen=True)
class Command:
    module: str
    config: str
    help: str
    positional: str | None = None
    make: str = "make_config"
    """The module's ``make(preset) -> config``; empty for a config without presets (its defaults)."""
    runner: str = "run"
    cost: str = ""
    """What the command costs when that does not follow from the preset's per-model cost (the demo)."""


COMMANDS: dict[str, Command] = {
    "generate": Command("pokeworld.sim.generate", "GenerateConfig", "simulate a PokeWorld corpus", "out"),
    "stats": Command("pokeworld.sim.stats", "StatsConfig", "a corpus's observable statistics beside the paper's",
                     "data"),
    "certify": Command("pokeworld.certify", "CertifyConfig", "recoverability certificates for a corpus", "data"),
    "certify-curve": Command("pokeworld.certificate_curve", "CurveConfig",
                             "certificate R² against certificate-fit episodes (where each estimator plateaus)", "data"),
    "train": Command("pokeworld.train", "TrainConfig", "train one X-JEPA variant"),
    "train-stacked": Command("pokeworld.train.stacked", "StackedConfig",
                             "train a grid of runs (variants × seeds × λ) stacked in one process",
                             runner="run_config"),
    "probe": Command("pokeworld.evaluate.measure", "MeasureConfig", "probe and evaluate one trained run", "run_dir"),
    "map": Command("pokeworld.experiments", "MapConfig", "the identifiability map end to end", "out"),
    "demo": Command("pokeworld.experiments", "MapConfig", "small map on CPU in minutes", "out",
                    make="make_demo_config",
                    cost="≈ 7.5 min on 2 CPU cores: 2,400 episodes, four 2,200-step models of train's "
                         "'demo' preset, demo certificates"),
    "pairs": Command("pokeworld.sim.pairs", "PairsConfig", "matched-pairs figure", "out"),
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
                           "record PokeWorld episodes with a stable-worldmodel policy through swm.World", make=""),
    "swm-export": Command("pokeworld.swm.dataset", "ExportConfig",
                          "export a store to stable-worldmodel's HDF5 format (touch, labels, parameters as columns)",
                          "store", make="", runner="run_export"),
    "swm-import": Command("pokeworld.swm.dataset", "ImportConfig",
                          "import a stable-worldmodel PokeWorld dataset (HDF5 or Lance) into a store", "source",
                          make="", runner="run_import"),
    "swm-certify-lewm": Command("pokeworld.swm.lewm", "LeWMConfig",
                                "train stable-worldmodel's LeWM on a store and certify it (beside X-JEPA runs)",
                                "data"),
    "swm-plan": Command("pokeworld.swm.costable", "SwmPlanConfig",
                        "push-to-goal with stable-worldmodel's CEM / iCEM / MPPI on X-JEPA costs, beside our planner",
                        "plan.out"),
}

#: What ``--preset`` costs, shown by ``pokeworld --help`` and each command's ``--help`` (timings:
#: docs/model.md "Benchmark"; the same numbers as the comment on ``pokeworld.train.PRESETS``).
PRESET_COSTS: dict[str, str] = {
    "tiny": "seconds; smoke runs and the unit tests (too small for meaningful numbers)",
    "cpu": ("2 CPU cores; ≈ 0.26 s/step on one core, ≈ 20 min per 4,000-step model with two side by side "
            "(the default)"),
    "paper": ("GPU; the paper's sizes: on one H100 0.041 s/step (fast path) ≈ 14 min per 20k-step model, "
              "0.030 with --compile; stacked, 0.027 s per model-step for six models in one process"),
    "demo": ("train only: the cpu model with 64-wide proprio/touch encoders at batch 8, 2,200 steps, "
             "≈ 2.7 min per model with two side by side (what `pokeworld demo` trains)"),
}


def usage() -> str:
    """Top-level help: the module docstring, one line per command, the cost of each preset."""
    width = max(map(len, COMMANDS)) + 2
    lines = [__doc__.strip(), "", "commands:"]
    lines += [f"  {name:{width}s}{c.help}" for name, c in COMMANDS.items()]
    lines += ["", "presets (--preset):"]
    lines += [f"  {name:{width}s}{cost}" for name, cost in PRESET_COSTS.items()]
    return "\n".join(lines)


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
    apart from the tuple's values, so put the positional first in that case.
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
            out += [f"--{positional.replace('_', '-')}", tok]
            found = True
        else:
            out.append(tok)
        i += 1
    return preset, out


def main(argv: list[str] | None = None) -> int:
    import tyro

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
        mod = importlib.import_module(cmd.module)
        cls = getattr(mod, cmd.config)
        preset, rest = split_args(argv, cmd.positional, _flag_arity(cls))
        if not cmd.make and preset != "cpu":
            raise ConfigError(f"{name} has no presets; drop --preset {preset}")
        default = getattr(mod, cmd.make)(preset) if cmd.make else cls()
        # the costs are per trained model, so only the commands that train quote them
        cost = cmd.cost or (PRESET_COSTS.get(preset) if cmd.config in ("TrainConfig", "MapConfig", "RealConfig")
                            else None)
        cfg = tyro.cli(cls, default=default, args=rest, prog=f"pokeworld {name}",
                       description=f"{cmd.help} (preset {preset!r}" + (f": {cost})" if cost else ")"))
        getattr(mod, cmd.runner)(cfg)
    except PokeworldError as e:
        print(f"pokeworld {name}: error: {e}", file=sys.stderr)
        return 2
    except FloatingPointError as e:
        print(f"pokeworld {name}: training diverged: {e}", file=sys.stderr)
        return 3
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
