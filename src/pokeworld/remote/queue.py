"""The paper-budget queue of GPU allocations: which runs come first, and how a run is named on the command line
(``VARIANT@SEED`` for a run of the factorial, the map's run name for any other experiment's run). Shared by the
allocation driver (:mod:`.run`) and the plan of the next allocation (:func:`.allocations.plan`); and
the one place a word taken from a returned record becomes part of a command line a
user pastes into a shell (:func:`run_word`, :func:`shell_line`): each word is first checked against what it can be
(a known variant, a seed that is a small non-negative integer, an environment variable's name), then quoted with
:func:`shlex.quote`, so a record cannot make the printed command run anything."""

from __future__ import annotations

import re
import shlex
from typing import TYPE_CHECKING

from ..errors import ConfigError
from ..models.xjepa import VARIANTS

if TYPE_CHECKING:
    from ..experiments.runs import RunSpec

PRIORITY = ("VFX@0", "VF@0", "V@0", "VX_t@0", "VX_p@0", "VX@0", "VFX@1", "VF@1", "V@1", "VX_t@1", "VX_p@1", "VX@1")
"""The factorial at the paper's budget: every variant at seed 0 (the central comparison VFX against VF first), then
the same at seed 1 (the paper's tables are means of two seeds). The head of :func:`paper_queue`."""
FACTORIAL_ORDER = ("VFX", "VF", "V", "VX_t", "VX_p", "VX")
"""The factorial's variants in the queue's order."""
#: The whole paper at its budget, experiment by experiment in priority order: (experiment, seeds, what it
#: reproduces). Each experiment's runs are the map's own (its module's ``specs``), so a lease trains exactly what
#: ``pokeworld map --preset paper --experiments NAME`` would.
PAPER_QUEUE: tuple[tuple[str, tuple[int, ...], str], ...] = (
    ("factorial", (0, 1), "finding 1, Table 'targets': targets, not inputs, decide content (two seeds)"),
    ("factorial", (2,), "the third seed of the paper's current revision"),
    ("lazy", (0,), "finding 2, the lazy equilibrium: the single-horizon factorial"),
    ("lambda", (0, 1), "finding 3, Table 'lambda': the SIGReg dose-response (two seeds)"),
    ("lambda_factorial", (0,), "finding 1 at λ 0.1 (App. C): the factorial's ordering is unchanged"),
    ("controls", (0,), "finding 4, objective attribution: system-ID head, Gaussian NLL, reconstruction"),
    ("attributes", (0,), "finding 4, the attribute matrix: biased and gained corpora"),
    ("dose_touch", (0,), "finding 4, dose-response 1: the touch contact weight"),
    ("dose_glide", (0,), "finding 4, dose-response 2: the glide loss weight"),
    ("ledger", (0,), "finding 4, the γ ledger: motion channel and motion targets"),
    ("coverage", (0,), "finding 4, coverage: a contact-poor corpus"),
    ("frame_averaged", (0,), "finding 4, frame-averaged touch"),
    ("coordinate", (0,), "finding 4, the coordinate test: the flow corpus"),
    ("tokens", (0,), "finding 4, token-level SIGReg across the factorial"),
    ("belief", (0, 1), "the belief objective and whole-episode history"),
)
RUN_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,199}")
"""A run's name as the map makes it (letters, digits, '.', '_', '-'): safe as a shell word, quoted all the same."""


def parse_token(token: str, known: set[str] | frozenset[str] | None = None) -> str:
    """The canonical queue token of ``token``: ``VARIANT@SEED`` for ``VARIANT`` or ``VARIANT@SEED`` (a run of the
    factorial), else a run name of the map (one of ``known`` when given); ConfigError otherwise."""
    variant, at, seed = token.partition("@")
    if variant in VARIANTS:
        if at and not (seed.isascii() and seed.isdigit() and len(seed) <= 10):
            raise ConfigError(f"{token[:80]!r} is not a run (VARIANT@SEED needs an integer seed)")
        return "{}@{}".format(*checked_key(variant, int(seed or 0), f"run {token!r}"))
    if at or not RUN_NAME.fullmatch(token) or (known is not None and token not in known):
        raise ConfigError(f"{token[:80]!r} is not a run: VARIANT or VARIANT@SEED (a variant of {list(VARIANTS)}), "
                          "or the name of one of the map's runs (merge_allocations.py --plan prints them)")
    return token


def factorial_key(token: str) -> tuple[str, int] | None:
    """(variant, seed) of a factorial token (``VARIANT@SEED``), None for another experiment's run name."""
    variant, at, seed = token.partition("@")
    return (variant, int(seed)) if at else None


def token_of(s: RunSpec) -> str:
    """The queue token of run ``s``: ``VARIANT@SEED`` for the factorial's, its name for any other."""
    return f"{s.train['variant']}@{s.seed}" if s.experiment == "factorial" else s.name


def catalog(preset: str = "paper", seeds: tuple[int, ...] = (0, 1, 2)) -> dict[str, RunSpec]:
    """Every experiment's runs at ``preset`` and ``seeds`` with every variant, by queue token (a run two experiments
    list is the first's, as the map trains it once)."""
    from ..experiments import stages
    from ..experiments.presets import make_config
    from ..experiments.registry import EXPERIMENTS

    c = make_config(preset, experiments=tuple(EXPERIMENTS), seeds=tuple(sorted(set(seeds))), variants=tuple(VARIANTS))
    return {token_of(s): s for s in stages.all_specs(c)}


def paper_queue(preset: str = "paper") -> list[str]:
    """The queue of :data:`PAPER_QUEUE` at ``preset``: each experiment's runs at its seeds, the factorial's in
    :data:`FACTORIAL_ORDER` seed by seed, every run once."""
    specs = catalog(preset, tuple(sorted({s for _, seeds, _ in PAPER_QUEUE for s in seeds})))
    out: list[str] = []
    for exp, seeds, _ in PAPER_QUEUE:
        group = [(t, s) for t, s in specs.items() if s.experiment == exp and s.seed in seeds]
        if exp == "factorial":
            group.sort(key=lambda ts: (ts[1].seed, FACTORIAL_ORDER.index(ts[1].train["variant"])))
        out += [t for t, _ in group if t not in out]
    return out


MAX_SEED = 2**31 - 1
"""Largest seed a run may have (torch and NumPy seeds are 32-bit)."""
ENV_NAME = re.compile(r"[A-Z_][A-Z0-9_]*")


def checked_key(variant: object, seed: object, where: str = "a record") -> tuple[str, int]:
    """(variant, seed) when ``variant`` is a known variant and ``seed`` an integer in [0, :data:`MAX_SEED`] (not a
    string, float or bool); ConfigError naming ``where`` otherwise."""
    if not isinstance(variant, str) or variant not in VARIANTS:
        raise ConfigError(f"{where}: variant {str(variant)[:40]!r} is not one of {list(VARIANTS)}; the record is "
                          "damaged or was edited")
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
        raise ConfigError(f"{where}: seed {str(seed)[:40]!r} is not an integer in [0, {MAX_SEED}]; the record is "
                          "damaged or was edited")
    return variant, seed


def token(key: tuple[str, int]) -> str:
    return f"{key[0]}@{key[1]}"


def run_word(key: tuple[object, object], where: str = "a record") -> str:
    """``VARIANT@SEED`` for a command line, after :func:`checked_key`."""
    return token(checked_key(key[0], key[1], where))


def word_of(name: str, variant: object, seed: object, other_names: set[str], where: str = "a record") -> str:
    """The queue token of a returned run: ``name`` itself when it is a run of another experiment than the factorial
    (one of ``other_names``), else ``VARIANT@SEED`` of its config (a known variant, an integer seed); ConfigError
    naming ``where`` otherwise (the word goes into a printed command)."""
    key = checked_key(variant, seed, where)
    return name if name in other_names and RUN_NAME.fullmatch(name) else token(key)


def shell_line(argv: list[str], env: dict[str, str] | None = None) -> str:
    """``argv`` (preceded by ``NAME=value`` assignments) as one shell command line, every word and value quoted
    (:func:`shlex.quote`): pasted into a shell it runs exactly ``argv``, whatever characters the words hold.
    ConfigError for an environment name that is not one (``[A-Z_][A-Z0-9_]*``)."""
    words = []
    for name, value in (env or {}).items():
        if not ENV_NAME.fullmatch(name):
            raise ConfigError(f"{name[:40]!r} is not an environment variable's name")
        words.append(f"{name}={shlex.quote(str(value))}")
    return " ".join(words + [shlex.quote(str(w)) for w in argv])


def folder_list(folders: list[str]) -> str:
    """Folders as one ALLOC_RESUME value: each quoted (:func:`shlex.quote`), so a folder with a space or a quote
    stays one folder when :func:`split_folder_list` reads it back."""
    return " ".join(shlex.quote(f) for f in folders)


def split_folder_list(value: str) -> list[str]:
    """The folders of an ALLOC_RESUME value (:func:`folder_list`'s, or plain space-separated ones); ConfigError for
    an unbalanced quote."""
    try:
        return shlex.split(value)
    except ValueError as e:
        raise ConfigError(f"ALLOC_RESUME={value[:80]!r} is not a list of folders ({e}); quote a folder with spaces "
                          "as merge_allocations.py --plan prints it") from None


def order_queue(requested: list[tuple[str, int]], finished: set[tuple[str, int]],
                resumable: set[tuple[str, int]]) -> list[tuple[str, int]]:
    """``requested`` without the finished runs, those with a checkpoint first, each group in the requested order."""
    todo = [r for r in dict.fromkeys(requested) if r not in finished]
    return [r for r in todo if r in resumable] + [r for r in todo if r not in resumable]


__all__ = ["PRIORITY", "FACTORIAL_ORDER", "PAPER_QUEUE", "RUN_NAME", "MAX_SEED", "parse_token", "factorial_key",
           "token_of", "catalog", "paper_queue", "checked_key", "token", "run_word", "word_of", "shell_line",
           "folder_list", "split_folder_list", "order_queue"]
