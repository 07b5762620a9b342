"""Wall-clock time for training deadlines: one module attribute, so a test can fast-forward time for the trainer
and the map at once."""

import time


def wall_clock() -> float:
    """Unix time for ``deadline`` checks."""
    return time.time()
