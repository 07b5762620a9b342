"""A store without a touch stream (an swm environment's: its low-dimensional state in the proprio role, touch of width
0): each X-JEPA variant is wired as its name says — the state input exists only in VF and VFX, the state forecasting
target only in VX and VFX, and that target's gradient reaches the encoder — and such a store saves, loads and trains."""

import numpy as np
import pytest
import torch

from pokeworld import data
from pokeworld.data import Dataset
from pokeworld.models.xjepa import XJEPA
from pokeworld.train import config as TC
from pokeworld.train.single import run as train_run

STATE_INPUT = {"V": False, "VF": True, "VX": False, "VFX": True}
STATE_TARGET = {"V": False, "VF": False, "VX": True, "VFX": True}


def stateful_store(E=12, T=20, side=16, seed=0) -> Dataset:
    rng = np.random.default_rng(seed)
    frames = rng.integers(0, 255, (E, T + 1, side, side), dtype=np.uint8)
    state = np.cumsum(rng.normal(size=(E, T + 1, 5)), 1).astype(np.float32)
    return Dataset(frames=frames, proprio=state, touch=np.zeros((E, T + 1, 0), np.float32),
                   actions=rng.uniform(-1, 1, (E, T, 1)).astype(np.float32), labels={},
                   params={"gravity.z": rng.uniform(-20, 0, E).astype(np.float32)},
                   split=np.array([0] * 6 + [1] * 3 + [2] * 3, np.int8), manifest={"kind": "test"})


def model(variant: str) -> XJEPA:
    torch.manual_seed(0)
    return XJEPA(variant, proprio_dim=5, touch_dim=0, action_dim=1, image_size=16, channels=(4, 8, 8, 8),
                 latent_dim=16, width=16, depth=1, heads=2, vec_dim=8, horizons=(1, 4), dropout=0.0).eval()


def encoder_grad(m: XJEPA, batch: dict, proprio_weight: float) -> torch.Tensor:
    m.zero_grad(set_to_none=True)
    loss, _ = m.loss(batch, proprio_weight=proprio_weight, sigreg_dirs=16, sigreg_seed=3)
    loss.backward()
    return torch.cat([p.grad.flatten() for p in m.encoder.cnn.parameters()])


@pytest.mark.parametrize("variant", ["V", "VF", "VX", "VFX"])
def test_each_variant_reads_and_forecasts_the_state_as_named(variant):
    m, ds = model(variant), stateful_store()
    assert ("proprio" in m.inputs) == STATE_INPUT[variant] == (m.encoder.proprio is not None)
    assert ("proprio" in m.targets) == STATE_TARGET[variant] == ("proprio" in m.modal_heads)
    assert "touch" not in m.inputs and "touch" not in m.targets and "touch" not in m.modal_heads
    batch = {"frames": torch.from_numpy(ds.frames[:4, :10]), "proprio": torch.from_numpy(ds.proprio[:4, :10]),
             "touch": torch.from_numpy(ds.touch[:4, :10]),
             "actions": torch.from_numpy(np.concatenate([ds.actions[:4, :9], np.zeros((4, 1, 1), np.float32)], 1))}
    # the state-forecast term's share of the encoder's gradient: nonzero exactly when the state is a target
    diff = (encoder_grad(m, batch, 5.0) - encoder_grad(m, batch, 0.0)).abs().max().item()
    assert (diff > 1e-6) == STATE_TARGET[variant], diff
    # the state input changes the features exactly when it is read
    z = m.encode(batch["frames"], batch["proprio"], batch["touch"])
    z_other = m.encode(batch["frames"], batch["proprio"] + 3.0, batch["touch"])
    assert (not torch.allclose(z, z_other)) == STATE_INPUT[variant]


def test_a_store_without_touch_saves_loads_and_trains(tmp_path):
    ds = stateful_store()
    data.save(ds, tmp_path / "store")
    back = data.load(tmp_path / "store")
    assert back.touch.shape == (12, 21, 0) and np.array_equal(back.proprio, ds.proprio)
    cfg = TC.make_config("tiny", variant="VFX", data=str(tmp_path / "store"), out=str(tmp_path / "run"), window=12,
                         horizons=(1, 4))
    run_dir = train_run(cfg)
    assert (run_dir / "DONE").exists()
