"""One place that imports stable-worldmodel, so a missing extra is one clear error, not a deep traceback."""

from __future__ import annotations

from types import ModuleType

from ..errors import ConfigError

SWM_VERSION = "0.1.1"
"""The stable-worldmodel release the bridge is written and tested against (the ``swm`` extra pins it)."""
INSTALL = "python -m venv .venv-swm && .venv-swm/bin/pip install -e '.[swm]', then run .venv-swm/bin/pokeworld"
"""The install line the refusals give: a separate environment (the extra replaces the core's torch)."""


def stable_worldmodel() -> ModuleType:
    """The imported ``stable_worldmodel`` package, or a ConfigError saying how to install the extra."""
    try:
        import stable_worldmodel
    except ImportError as e:
        raise ConfigError(f"the stable-worldmodel bridge needs the swm extra ({e}); install it in an environment of "
                          f"its own, since it moves torch to 2.14.1: {INSTALL} (docs/stable_worldmodel.md)") from e
    except RuntimeError as e:  # torchvision built for another torch raises at import ("torchvision::nms")
        raise ConfigError("stable-worldmodel imports torchvision, which does not load beside this torch build "
                          f"({e}); use an environment of its own with the swm extra's pins: {INSTALL}") from e
    return stable_worldmodel
