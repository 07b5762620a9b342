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

from .errors import PokeworldError


@dataclass(frozen=True)
class Command:
    module: str
    config: str
    help: str
    positional: str | None = None
    make: str = "make_config"
    runner: str = "run"


COMMANDS: dict[str, Command] = {
    "generate": Command("pokeworld.sim.generate", "GenerateConfig", "simulate a PokeWorld corpus", "out"),
    "certify": Command("pokeworld.certify", "CertifyConfig", "recoverability certificates for a corpus", "data"),
    "train": Command("pokeworld.train", "TrainConfig", "train one X-JEPA variant"),
    "probe": Command("pokeworld.evaluate.measure", "MeasureConfig", "probe and evaluate one trained run", "run_dir"),
    "map": Command("pokeworld.evaluate.experiment", "MapConfig", "the identifiability map end to end", "out"),
    "demo": Command("pokeworld.evaluate.experiment", "MapConfig", "small map on CPU in minutes", "out",
                    make="make_demo_config"),
    "pairs": Command("pokeworld.sim.pairs", "PairsConfig", "matched-pairs figure", "out"),
    "plan": Command("pokeworld.plan", "PlanConfig", "CEM push-to-goal with trained runs", "out"),
    "rh20t-convert": Command("pokeworld.real.rh20t", "ConvertConfig", "convert RH20T scenes to a store", "root"),
}


def _bool_flags(cls) -> set[str]:
    hints = typing.get_type_hints(cls)
    out = set()
    for f in dataclasses.fields(cls):
        if hints.get(f.name) is bool:
            name = f.name.replace("_", "-")
            out |= {f"--{name}", f"--no-{name}", f"--{f.name}", f"--no-{f.name}"}
    return out


def split_args(argv: list[str], positional: str | None, bool_flags: set[str]) -> tuple[str, list[str]]:
    """Pull ``--preset X`` out of ``argv`` and turn a bare positional into ``--<positional> value``."""
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
    out, found = [], False
    for j, tok in enumerate(rest):
        prev = rest[j - 1] if j else None
        bare = not tok.startswith("-") and (prev is None or not prev.startswith("-") or prev in bool_flags
                                            or "=" in prev)
        if bare and not found:
            out += [f"--{positional.replace('_', '-')}", tok]
            found = True
        else:
            out.append(tok)
    return preset, out


def main(argv: list[str] | None = None) -> int:
    import tyro

    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__)
        print("commands:")
        for name, c in COMMANDS.items():
            print(f"  {name:14s} {c.help}")
        return 0
    name, argv = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"pokeworld: unknown command {name!r}; choose one of {', '.join(COMMANDS)}", file=sys.stderr)
        return 2
    cmd = COMMANDS[name]
    try:
        mod = importlib.import_module(cmd.module)
        cls = getattr(mod, cmd.config)
        preset, rest = split_args(argv, cmd.positional, _bool_flags(cls))
        default = getattr(mod, cmd.make)(preset)
        cfg = tyro.cli(cls, default=default, args=rest, prog=f"pokeworld {name}",
                       description=f"{cmd.help} (preset {preset!r})")
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
