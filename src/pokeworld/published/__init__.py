"""Published numbers shown beside ours, never used as results of ours: :mod:`.paper`, the paper's (its tables and
text); :mod:`.release`, the per-run results of the code its authors released."""
