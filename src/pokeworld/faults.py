"""Named crash points, so tests can kill a process with SIGKILL at an exact place and check what survives.

``POKEWORLD_KILL_AT=<point>[:<n>]`` kills the process the ``n``-th time (default the first) it reaches
``crash_point(<point>)``; ``POKEWORLD_PAUSE_AT=<point>:<seconds>`` sleeps there once instead (a test that needs a
process to hold a lock for a while). Unset, a crash point costs one comparison. The points are where a real crash
would hurt most: between optimizer steps (``train_step``), after probes are fitted and before ``measure.json``
is written (``measure``), and between writing a file's temporary copy and renaming it (``rename:<file name>``).
"""

from __future__ import annotations

import os
import signal
import time


def _spec(var: str, default_arg: str) -> tuple[str, str] | None:
    """``<point>[:<arg>]`` from the environment (read once: the tests set it before the process starts)."""
    spec = os.environ.get(var, "")
    if not spec:
        return None
    point, _, arg = spec.rpartition(":")
    return (point, arg) if arg.replace(".", "", 1).isdigit() else (spec, default_arg)


_KILL, _PAUSE = _spec("POKEWORLD_KILL_AT", "1"), _spec("POKEWORLD_PAUSE_AT", "0")
_reached: dict[str, int] = {}


def crash_point(name: str) -> None:
    if _PAUSE and _PAUSE[0] == name and not _reached.get(f"pause:{name}"):
        _reached[f"pause:{name}"] = 1
        time.sleep(float(_PAUSE[1]))
    if _KILL and _KILL[0] == name:
        _reached[name] = _reached.get(name, 0) + 1
        if _reached[name] == int(_KILL[1]):
            os.kill(os.getpid(), signal.SIGKILL)


__all__ = ["crash_point"]
