"""Program-aligned training windows: the longest head's query lands on a program slot start, only as often as
asked, and runs that do not ask keep their sampling stream."""

import numpy as np
import pytest
import torch

from pokeworld.errors import ConfigError
from pokeworld.sim.policy import PROGRAM
from pokeworld.train.sampler import WindowSampler, program_aligned_starts


def test_aligned_starts_put_the_longest_query_on_a_slot_start():
    starts = program_aligned_starts(65, 24, 16)
    assert starts.tolist() == [9, 25, 41]
    query = starts + 24 - 1 - 16  # the window position whose Δ = 16 target is the window's last frame
    assert torch.all(query % PROGRAM == 0) and torch.all(starts + 24 <= 65)
    assert program_aligned_starts(17, 18, 16).numel() == 0


def _sampler(ds, share):
    return WindowSampler(ds, ds.episodes("train"), 16, 24, torch.device("cpu"), seed=5, aligned_share=share)


def test_a_share_of_one_aligns_every_window_and_zero_keeps_the_old_stream(tiny_dataset):
    aligned = set(program_aligned_starts(tiny_dataset.frames.shape[1], 24, 16).tolist())
    _, s = _sampler(tiny_dataset, 1.0).draw(256, torch.Generator().manual_seed(0))
    assert set(s.tolist()) <= aligned and len(set(s.tolist())) == len(aligned)
    # share 0 draws exactly what the sampler drew before the option existed
    plain = _sampler(tiny_dataset, 0.0)
    e, s = plain.draw(64, torch.Generator().manual_seed(1))
    g = torch.Generator().manual_seed(1)
    e_ref = torch.multinomial(plain.weights, 64, replacement=True, generator=g)
    torch.testing.assert_close((e, s), (e_ref, torch.randint(0, plain.num_starts, (64,), generator=g)))


def test_a_share_of_a_half_aligns_about_half_the_windows(tiny_dataset):
    aligned = set(program_aligned_starts(tiny_dataset.frames.shape[1], 24, 16).tolist())
    _, s = _sampler(tiny_dataset, 0.5).draw(4000, torch.Generator().manual_seed(2))
    hit = np.isin(s.numpy(), list(aligned)).mean()
    # aligned by choice (0.5) plus uniform starts that happen to be aligned (0.5 · 3 / 42)
    assert hit == pytest.approx(0.5 + 0.5 * len(aligned) / (tiny_dataset.frames.shape[1] - 24 + 1), abs=0.03)


def test_bad_shares_are_refused():
    from pokeworld.train.config import make_config

    with pytest.raises(ConfigError, match="program_aligned_share"):
        make_config("tiny", program_aligned_share=1.5)
