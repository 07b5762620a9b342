"""Measurement of trained X-JEPA runs (probes, prediction quality, glide tests) and the identifiability map."""
