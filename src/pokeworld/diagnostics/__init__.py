"""Diagnostics of trained runs that are not part of the map's tables, run by hand.

:mod:`.nll_precision` (``scripts/nll_precision.py``) and :mod:`.token_state` (``scripts/token_state_probe.py``).
"""
