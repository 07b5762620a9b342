"""Diagnostics of trained runs that are not part of the map's tables, run by hand.

:mod:`.nll_precision` (``scripts/nll_precision.py``), :mod:`.token_state` (``scripts/token_state_probe.py``) and
:mod:`.head_capacity` (``scripts/head_capacity.py``).
"""
