"""The torch.compile mode of a run: validated, resumable, and handed to torch.compile as named."""

import pytest
import torch

from pokeworld.errors import ConfigError
from pokeworld.train.config import RESUMABLE_FIELDS, make_config


def test_compile_mode_is_validated_and_needs_compile():
    with pytest.raises(ConfigError, match="compile_mode"):
        make_config("tiny", compile=True, compile_mode="fastest")
    with pytest.raises(ConfigError, match="--compile"):
        make_config("tiny", compile_mode="reduce-overhead")
    assert make_config("tiny", compile=True, compile_mode="reduce-overhead").compile_mode == "reduce-overhead"
    assert "compile_mode" in RESUMABLE_FIELDS  # a run may resume under another mode (same maths)


def test_the_trainer_compiles_its_loss_in_the_named_mode(monkeypatch, tmp_path, tiny_dataset):
    from pokeworld.data import save
    from pokeworld.train import single

    seen = []

    def recording_compile(module, mode=None, **kw):  # record the call, train eagerly (compiling on a CPU is slow)
        seen.append(mode)
        return module

    monkeypatch.setattr(torch, "compile", recording_compile)
    data = save(tiny_dataset, tmp_path / "data")
    single.run(make_config("tiny", data=str(data), out=str(tmp_path / "run"), steps=2, compile=True,
                           compile_mode="reduce-overhead"))
    assert seen == ["reduce-overhead"]
