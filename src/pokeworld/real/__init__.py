"""Real-robot data: the RH20T loader/converter (:mod:`pokeworld.real.rh20t`) and a
generator of small fixture scenes in RH20T's on-disk layout (:mod:`pokeworld.real.fixtures`), and a
synthetic RH20T-layout corpus from PokeWorld episodes with known force (:mod:`pokeworld.real.synthetic`).

See docs/rh20t.md for the format facts relied on and every choice made.
"""
