"""Frozen-state extraction shared by every measurement (simulator ``measure``, ``protocol``, real data).

Encoder latents per episode, and the predictor (trunk) state at the last observation of fixed-length
windows, read leak-free by default: the action taken *after* the probed observation is replaced by the
neutral (raw zero) action, because on both corpora that action carries information about the future
(the scripted policy reads the privileged object state; RH20T actions are achieved TCP deltas).
"""

from __future__ import annotations

import numpy as np
import torch

from ..data import Dataset
from ..errors import ConfigError
from ..sim.envs import vision_frames

PROBE_DEVICES = ("auto", "host", "model")
"""Where probes of a model's states run (``MeasureConfig.probe_device``, :func:`probes_on_device`)."""


def model_device(model) -> torch.device:
    """The device a model's tensors live on (measurement runs the model there); the CPU for a model that holds
    none (a planted or wrapped model)."""
    for tensors in (getattr(model, "parameters", None), getattr(model, "buffers", None)):
        t = next(iter(tensors()), None) if callable(tensors) else None
        if t is not None:
            return t.device
    return torch.device("cpu")


def probes_on_device(choice: str, model) -> bool:
    """Whether ``model``'s states stay on its device and are probed there in torch (:mod:`pokeworld.regressors`,
    tensor inputs) rather than copied to the host and probed in numpy / sklearn. ``choice`` (:data:`PROBE_DEVICES`):
    'auto' — on a CUDA model, so a GPU measurement copies back only its R² numbers; on the CPU the numpy path every
    record was computed with; 'model' — always (on a CPU model: the torch path on the CPU, which the tests compare
    with the numpy one); 'host' — never."""
    if choice not in PROBE_DEVICES:
        raise ConfigError(f"probe device must be one of {list(PROBE_DEVICES)}, got {choice!r}")
    return choice == "model" or (choice == "auto" and model_device(model).type == "cuda")


def as_model_input(model, x) -> torch.Tensor:
    """An array of latents as a tensor on the model's device (the model moves frames and actions itself)."""
    return torch.as_tensor(x, device=model_device(model))


@torch.no_grad()
def encode_observations(model, obs: dict, batch: int = 1024, keep_tokens: bool = False) -> np.ndarray:
    """Single observations {"vision" (N, H, W, 1), "proprio" (N, P), "touch" (N, T)} -> (N, D) float32 encoder
    latents, ``batch`` at a time; token models give the mean over tokens, or with ``keep_tokens`` (N, S, D)."""
    out, frames = [], vision_frames(obs["vision"])
    for i in range(0, len(frames), batch):
        z = model.encode(frames[i:i + batch, None], *(obs[k][i:i + batch, None] for k in ("proprio", "touch")))[:, 0]
        out.append(z.mean(1) if z.dim() == 3 and not keep_tokens else z)
    return torch.cat(out).float().cpu().numpy()


@torch.no_grad()
def encode_episodes(model, ds: Dataset, episodes: np.ndarray, batch: int = 64, keep_tokens: bool = False,
                    on_device: bool = False):
    """Encoder latents for whole episodes: (E', T+1, D) float32; token models give the mean over tokens, or
    with ``keep_tokens`` every token, (E', T+1, S, D). A numpy array, or with ``on_device`` a tensor on the
    model's device."""
    out = []
    model.eval()
    for i in range(0, len(episodes), batch):
        e = episodes[i:i + batch]
        z = model.encode(ds.frames[e], ds.proprio[e], ds.touch[e])
        if z.dim() == 4 and not keep_tokens:
            z = z.mean(2)
        out.append(z.float() if on_device else z.float().cpu().numpy())
    return torch.cat(out) if on_device else np.concatenate(out)


@torch.no_grad()
def _trunk_at(model, z_win, a_win: np.ndarray, index: int, batch: int = 512, per_token: bool = False,
              on_device: bool = False):
    trunk = model.trunk_tokens if per_token else model.trunk
    out = []
    for i in range(0, len(z_win), batch):
        zt = as_model_input(model, z_win[i:i + batch])
        h = trunk(zt, a_win[i:i + batch])
        out.append(h[:, index].float() if on_device else h[:, index].float().cpu().numpy())
    return torch.cat(out) if on_device else np.concatenate(out)


def padded_actions(ds: Dataset) -> np.ndarray:
    """Actions aligned with observations: (E, T+1, Da), the last one zero."""
    return np.concatenate([ds.actions, np.zeros_like(ds.actions[:, :1])], 1)


class EpisodeLatents:
    """Encoder latents of a set of episodes, indexable by global episode id.

    ``z`` (E', T+1, D) is what decoders and probes of the latent read (token models: mean over tokens);
    ``trunk_input`` is what the predictor reads — ``z`` itself, or every token for a token model, whose
    predictor attends over the S tokens of each step. ``on_device``: ``trunk_input`` stays a tensor on the model's
    device, so window states are computed without a round trip through the host; ``z`` is a host copy either way
    (the position decoders are fit there)."""

    def __init__(self, model, ds: Dataset, episodes: np.ndarray, batch: int, on_device: bool = False):
        self.index = {int(e): i for i, e in enumerate(episodes)}
        tokens = bool(getattr(model, "tokens", False))
        full = encode_episodes(model, ds, episodes, batch, keep_tokens=tokens, on_device=on_device)
        host = full.cpu().numpy() if on_device else full
        self.z = host.mean(2) if tokens else host
        self.trunk_input = full

    def gather(self, w, trunk: bool = False):
        """Latents of every window (W, L, D); ``trunk=True``: the predictor's input (token models (W, L, S, D)),
        a tensor on the model's device when the latents were kept there."""
        rows = np.array([self.index[int(e)] for e in w.episode])
        t = w.start[:, None] + np.arange(w.length)[None, :]
        src = self.trunk_input if trunk else self.z
        if isinstance(src, torch.Tensor):
            rows, t = torch.as_tensor(rows, device=src.device), torch.as_tensor(t, device=src.device)
        return src[rows[:, None], t]


def window_states(model, ds: Dataset, lat: EpisodeLatents, w, acts: np.ndarray,
                  neutral_last_action: bool = True, per_token: bool = False, on_device: bool = False):
    """Predictor state at the last observation of every window: (W, width); ``per_token``: every token's
    state (W, S, width) — for a token model the probed state is their mean (S = 1 for the global variants).
    A numpy array, or with ``on_device`` a float32 tensor left on the model's device.

    ``neutral_last_action`` replaces the action taken after that observation by raw zeros before the
    trunk sees it: the policy chose that action from the privileged object state, so a state conditioned
    on it can expose the object state without the model having inferred anything. Zeros are the padding
    every training episode ends with, so the trunk has seen this input.
    """
    a = w.gather(acts)
    if neutral_last_action:
        a = neutral_last(a)
    return _trunk_at(model, lat.gather(w, trunk=True), a, w.length - 1, per_token=per_token, on_device=on_device)


def neutral_last(a_win: np.ndarray) -> np.ndarray:
    """Window actions (W, L, Da) with the last one, taken after the probed observation, set to raw zeros.

    The leak-free readout convention shared by :func:`window_states` and :mod:`pokeworld.protocol`;
    a copy, so the dataset's actions are untouched.
    """
    a = np.array(a_win, copy=True)
    a[:, -1] = 0.0
    return a
