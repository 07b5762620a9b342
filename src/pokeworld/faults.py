"""Named crash points, so tests can kill a process with SIGKILL at an exact place and check what survives.

``POKEWORLD_KILL_AT=<point>[:<n>]`` kills the process the ``n``-th time (default the first) it reaches
``crash_point(<point>)``; ``POKEWORLD_PAUSE_AT=<point>:<seconds>`` sleeps there once instead (a test that needs a
process to hold a lock for a while). Unset, a crash point costs one dictionary lookup. The points are where a real crash
would hurt most: between optimizer steps (``train_step``), after probes are fitted and before ``measure.json``
is written (``measure``), and between writing a file's temporary copy and renaming it (``rename:<file name>``).
"""

from __future__ import annotations

import os
import signal
import time

_reached: dict[str, int] = {}


def crash_point(name: str) -> None:
    pause = os.environ.get("POKEWORLD_PAUSE_AT")
    if pause and pause.rpartition(":")[0] == name and not _reached.get(f"pause:{name}"):
        _reached[f"pause:{name}"] = 1
        time.sleep(float(pause.rpartition(":")[2]))
    spec = os.environ.get("POKEWORLD_KILL_AT")
    if not spec:
        return
    point, _, nth = spec.rpartition(":") if spec.rpartition(":")[2].isdigit() else (spec, "", "1")
    if point != name:
        return
    _reached[name] = _reached.get(name, 0) + 1
    if _reached[name] == int(nth):
        os.kill(os.getpid(), signal.SIGKILL)


__all__ = ["crash_point"]
