"""Named presets layered over dataclass defaults (dreamerv3 style).

Every experiment config is a ``@dataclass`` whose fields carry docstrings (tyro
shows them as ``--help``). A module declares ``PRESETS = {"tiny": {...},
"cpu": {...}, "paper": {...}}``: each preset is a dict of field overrides
applied on top of the dataclass defaults. Nested dataclasses are overridden
with nested dicts.

Every config checks its own fields when it is made (:func:`check_fields`, called from its ``__post_init__`` or
``validate``): each field holds the type it is annotated with, every number is finite and inside the range the
class declares in ``LIMITS`` (field name -> :class:`Limit`). A number from the command line or from a store's
manifest is data: NaN, a negative seed or a 60,000-pixel frame must be refused in one line before anything is
created or allocated, not end in a traceback, a hang or a store with no training episodes.
"""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
import functools
import json
import math
import numbers
import types
import typing
from typing import Any, Iterator, Mapping, TypeVar

from .errors import ConfigError, PokeworldError

PRESET_NAMES = ("tiny", "cpu", "paper")
T = TypeVar("T")


@dataclasses.dataclass(frozen=True)
class Limit:
    """The values a numeric config field (or each number of a tuple field) may take: ``lo`` to ``hi``, ``lo``
    itself excluded when ``above`` (a length or a rate must be positive, not merely non-negative)."""

    lo: float
    hi: float
    above: bool = False

    def admits(self, value: float) -> bool:
        return (value > self.lo if self.above else value >= self.lo) and value <= self.hi

    def __str__(self) -> str:
        return f"in {'(' if self.above else '['}{_number(self.lo)}, {_number(self.hi)}]"


def _number(x: float) -> str:
    return str(x) if isinstance(x, int) else f"{x:g}"


SEED = Limit(0, 2**32 - 1)
"""Seeds: what numpy's SeedSequence and torch both take as one 32-bit word (a negative seed is a traceback)."""
FRACTION = Limit(0, 1)
"""Shares and probabilities."""


def positive(hi: float) -> Limit:
    """A length, mass or rate: above 0, at most ``hi``."""
    return Limit(0, hi, above=True)


def shown(value: Any) -> str:
    """``repr`` cut to a readable length: a value from a damaged file may be a megabyte of list."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _is_int(value: Any) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _is_real(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


@functools.cache
def _limits(cls: type) -> dict[str, Limit]:
    """The ``LIMITS`` of ``cls`` and of the classes it derives from (a subclass's own win)."""
    out: dict[str, Limit] = {}
    for klass in reversed(cls.__mro__):
        out.update(vars(klass).get("LIMITS", {}))
    return out


def _number_problem(value: Any, integer: bool, limit: Limit | None) -> str | None:
    """What is wrong with ``value`` as a number of the field (None: nothing)."""
    kind = "integer" if integer else "finite number"
    if limit is not None and limit.lo == 0 and limit.hi != 1 and not integer:
        kind = ("positive " if limit.above else "non-negative ") + kind
    kind = ("an " if kind[0] in "aeiou" else "a ") + kind + (f" {limit}" if limit else "")
    # an int is finite (and math.isfinite overflows on one past 1e308); a NaN fails every comparison
    if not (_is_int(value) if integer else _is_real(value)) or (not _is_int(value) and not math.isfinite(value)) \
            or (limit is not None and not limit.admits(value)):
        return f"must be {kind}"
    return None


def _problem(value: Any, tp: Any, limit: Limit | None) -> str | None:
    """What is wrong with ``value`` as a value of the annotated type ``tp`` (None: nothing). Types this does not
    know (paths, callables) are left to the config's own checks, but any number is still checked finite."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if tp is bool:
        return None if isinstance(value, bool) else "must be true or false"
    if tp is int or tp is float:
        return _number_problem(value, tp is int, limit)
    if tp is str:
        return None if isinstance(value, str) else "must be a string"
    if dataclasses.is_dataclass(tp):
        return None if isinstance(value, tp) else f"must be a {tp.__name__} (a group of settings)"
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        arms = [a for a in args if a is not type(None)]
        problems = [_problem(value, a, limit) for a in arms]
        return None if None in problems else problems[0]
    if origin is tuple:
        return _sequence_problem(value, args, limit)
    return _number_problem(value, False, limit) if _is_real(value) else None


def _sequence_problem(value: Any, args: tuple, limit: Limit | None) -> str | None:
    """What is wrong with ``value`` as a ``tuple[...]`` field (a JSON file gives a list, which is as good)."""
    variadic = len(args) == 2 and args[1] is Ellipsis
    if not isinstance(value, (tuple, list)) or (not variadic and len(value) != len(args)):
        return f"must be a list of {'values' if variadic else len(args)}" + (f" {limit}" if limit else "")
    for i, item in enumerate(value):
        problem = _problem(item, args[0] if variadic else args[i], limit)
        if problem:
            return f"[{i}] {problem}"
    return None


def field_problem(value: Any, tp: Any, limit: Limit | None = None) -> str | None:
    """What is wrong with ``value`` (read from a record, e.g. a JSON file) as a value of the annotated type ``tp``
    within ``limit`` (None: nothing): the check :func:`check_fields` makes of a config's fields, for records that
    are not built into a config (a run's config.json as its readers read it)."""
    return _problem(value, tp, limit)


MAX_STORE_BYTES = 64 << 30
"""Most array bytes a store may declare in all (the paper's corpus is about 2.5 GiB): :func:`load` refuses more
before reading anything, so a forged header cannot make it allocate without bound."""


class FieldError(PokeworldError):
    """A config field outside its type or range, found while the command line is parsed. Not a ValueError on
    purpose: the argument parser (tyro) turns a ValueError raised while it builds the config into its multi-line
    help box; this one passes through, and the CLI prints it as one line like every other refusal."""


_PARSING = contextvars.ContextVar("pokeworld_parsing_command_line", default=False)


@contextlib.contextmanager
def parsing_command_line() -> Iterator[None]:
    """While the block runs, :func:`check_fields` raises :class:`FieldError` instead of ConfigError."""
    token = _PARSING.set(True)
    try:
        yield
    finally:
        _PARSING.reset(token)


def config_error(message: str) -> PokeworldError:
    """The error a config's own check raises: :class:`FieldError` while the command line is parsed (one line, not
    the parser's box), ConfigError otherwise."""
    return (FieldError if _PARSING.get() else ConfigError)(message)


def check_fields(cfg: Any) -> None:
    """ConfigError, in one line naming the field, unless every field of the dataclass ``cfg`` holds a value of
    its annotated type (bool, int, float, str, a nested config, tuples of them), every number in it is finite
    and inside its class's ``LIMITS``. Nested configs are not walked: each checked itself when it was made."""
    cls = type(cfg)
    hints, limits = _hints(cls), _limits(cls)
    for f in dataclasses.fields(cfg):
        value = getattr(cfg, f.name)
        problem = _problem(value, hints.get(f.name), limits.get(f.name))
        if problem:
            raise config_error(f"{cls.__name__}.{f.name}{'' if problem.startswith('[') else ' '}{problem}, "
                               f"got {shown(value)}")


def check_fractions(name: str, fractions: tuple[float, ...]) -> None:
    """ConfigError unless the (already finite, non-negative) shares ``fractions`` sum to 1."""
    if abs(sum(fractions) - 1) > 1e-6:
        raise ConfigError(f"{name} must sum to 1 (shares of the episodes), got {tuple(fractions)} "
                          f"(sum {sum(fractions):g})")


def apply_overrides(cfg: T, overrides: Mapping[str, Any]) -> T:
    """Return a copy of ``cfg`` with ``overrides`` applied (recursively for nested dataclasses)."""
    fields = {f.name: f for f in dataclasses.fields(cfg)}
    changes: dict[str, Any] = {}
    for key, value in overrides.items():
        if key not in fields:
            raise ConfigError(f"{type(cfg).__name__} has no field {key!r}; known fields: {sorted(fields)}")
        current = getattr(cfg, key)
        if dataclasses.is_dataclass(current) and isinstance(value, Mapping):
            changes[key] = apply_overrides(current, value)
        else:
            changes[key] = value
    return dataclasses.replace(cfg, **changes)


def from_preset(cls: type[T], presets: Mapping[str, Mapping[str, Any]], preset: str, **overrides: Any) -> T:
    """Build ``cls()`` with the named preset and then ``overrides`` applied."""
    if preset not in presets:
        raise ConfigError(f"unknown preset {preset!r} for {cls.__name__}; choose one of {sorted(presets)}")
    cfg = apply_overrides(cls(), presets[preset])
    if overrides:
        cfg = apply_overrides(cfg, overrides)
    return cfg


def to_dict(cfg: Any) -> dict:
    """JSON-serialisable dict of a (possibly nested) dataclass config."""
    return json.loads(json.dumps(dataclasses.asdict(cfg), default=str))


def from_dict(cls: type[T], data: Mapping[str, Any]) -> T:
    """Inverse of :func:`to_dict` for our flat-or-nested dataclass configs."""
    return apply_overrides(cls(), data)
