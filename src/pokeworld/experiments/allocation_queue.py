"""The paper-budget queue of GPU allocations: which runs come first, and how a run is named on the command line
(``VARIANT@SEED``). Shared by the allocation driver (:mod:`.allocation_run`) and the plan of the next allocation
(:func:`.allocations.plan`); and the one place a word taken from a returned record becomes part of a command line a
user pastes into a shell (:func:`run_word`, :func:`shell_line`): each word is first checked against what it can be
(a known variant, a seed that is a small non-negative integer, an environment variable's name), then quoted with
:func:`shlex.quote`, so a record cannot make the printed command run anything."""

from __future__ import annotations

import re
import shlex

from ..errors import ConfigError
from ..models.xjepa import VARIANTS

PRIORITY = ("VFX@0", "VF@0", "V@0", "VX_t@0", "VX_p@0", "VX@0", "VFX@1", "VF@1", "V@1", "VX_t@1", "VX_p@1", "VX@1")
"""The paper-budget queue: every factorial variant at seed 0 (the central comparison VFX against VF first), then the
same at seed 1 (the paper's tables are means of two seeds)."""

def parse_token(token: str) -> tuple[str, int]:
    """(variant, seed) of ``VARIANT`` or ``VARIANT@SEED``; ConfigError otherwise."""
    variant, at, seed = token.partition("@")
    if variant not in VARIANTS or (at and not (seed.isascii() and seed.isdigit() and len(seed) <= 10)):
        raise ConfigError(f"{token[:80]!r} is not a run (VARIANT or VARIANT@SEED, a variant of {list(VARIANTS)})")
    return checked_key(variant, int(seed or 0), f"run {token!r}")


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


__all__ = ["PRIORITY", "MAX_SEED", "parse_token", "checked_key", "token", "run_word", "shell_line", "folder_list",
           "split_folder_list", "order_queue"]
