"""Exception types raised for bad user input (configs, data files, options, values passed at run time).

They exist so the CLI can print one clear line instead of a traceback.
"""


class PokeworldError(Exception):
    """Base class for user-facing errors."""


class ConfigError(PokeworldError, ValueError):
    """An invalid configuration value or an unknown preset / variant."""


class DataError(PokeworldError, ValueError):
    """A missing, truncated, corrupt or non-finite dataset or sensor stream."""


class ModelError(PokeworldError, ValueError):
    """A user-supplied model that breaks its contract: wrong output shape or type, non-finite or overflowing states,
    or an exception raised inside it (chained as the cause)."""


class InputError(PokeworldError, ValueError):
    """A bad value passed at run time, neither configuration nor a data file: a non-finite or wrongly shaped action
    handed to an environment's ``step``, an observation array of the wrong layout."""
