"""Runs carried to a GPU and back: the paper-budget map trained in short device leases, its returns landed, merged
and completed on a CPU. In the order a lease uses them: :mod:`.queue` names the runs and orders them (run tokens,
the paper's queue, the words a printed command may hold); :mod:`.run` trains one allocation's queue on the device
(``python -m pokeworld.remote.run``, started by ``scripts/gpu_allocation.sh``), with :mod:`.share` running several
at once on its one GPU while that pays; :mod:`.pack` packs each run for the trip back (records, weights in
bfloat16, checkpoints, the return's limits and checks); then, back on this side, :mod:`.land` lands a lease's
return in the repository (``scripts/land_lease.py``: a released model per run, the lease's record);
:mod:`.allocations` reads returned or landed allocations and merges any number of them into one record
(``scripts/merge_allocations.py``), and :mod:`.plan` prints the next lease's queue and commands from them
(``--plan``); :mod:`.complete` computes on a CPU what the device left (certificates, MLP probes, the untrained
bound, planning: ``scripts/complete_allocations.py``) and :mod:`.cpu_side` attaches those numbers to the merged
record beside the paper's and the authors' released ones.

This package imports :mod:`pokeworld.experiments` (the map, its stages and presets); nothing there imports it.
"""
