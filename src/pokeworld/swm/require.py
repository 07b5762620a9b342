"""One place that imports stable-worldmodel, so a missing extra is one clear error, not a deep traceback."""

from __future__ import annotations

from types import ModuleType

from ..errors import ConfigError

SWM_VERSION = "0.1.1"
"""The stable-worldmodel release the bridge is written and tested against (the ``swm`` extra pins it)."""


def stable_worldmodel() -> ModuleType:
    """The imported ``stable_worldmodel`` package, or a ConfigError saying how to install the extra."""
    try:
        import stable_worldmodel
    except ImportError as e:
        raise ConfigError("the stable-worldmodel bridge needs the swm extra: pip install -e '.[swm]' "
                          f"(stable-worldmodel=={SWM_VERSION}; docs/stable_worldmodel.md) — {e}") from e
    except RuntimeError as e:  # torchvision built for another torch raises at import ("torchvision::nms")
        raise ConfigError("stable-worldmodel imports torchvision, which does not load beside this torch build "
                          f"({e}); install the swm extra's pins: pip install -e '.[swm]'") from e
    return stable_worldmodel
