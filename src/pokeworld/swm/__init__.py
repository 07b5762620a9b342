"""PokeWorld and the certificate-gated protocol inside stable-worldmodel (the ``swm`` extra).

Nothing in the core imports this package; each module here imports ``stable_worldmodel`` and fails with a
clear error when the extra is missing (:func:`pokeworld.swm.require.stable_worldmodel`).
"""
