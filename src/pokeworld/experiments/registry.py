"""Every experiment of the map, one module each (its run specs, its report section and its paper values), in one
place: the names the map accepts and the order results.md shows them in."""

from __future__ import annotations

from . import (
               attributes,
               belief,
               controls,
               coordinate,
               coverage,
               dose_glide,
               dose_touch,
               factorial,
               frame_averaged,
               lambda_factorial,
               lambda_sweep,
               lazy,
               ledger,
               planning,
               tokens,
)

#: Experiment modules in the order the map has always listed them (``--experiments`` names; a run shared by two
#: experiments is trained once, under the first that lists it).
MODULES = (factorial, lazy, lambda_sweep, lambda_factorial, coverage, frame_averaged, controls, dose_touch,
           dose_glide, attributes, belief, planning, coordinate, ledger, tokens)

#: name -> the function from a map config to the experiment's run specs.
EXPERIMENTS = {m.NAME: m.specs for m in MODULES}

#: Report sections in results.md order (each returns [] when its experiment did not run).
REPORT_ORDER = (factorial, tokens, lazy, lambda_sweep, lambda_factorial, coverage, frame_averaged, controls,
                dose_glide, dose_touch, attributes, belief, coordinate, ledger, planning)


__all__ = ["MODULES", "EXPERIMENTS", "REPORT_ORDER"]
