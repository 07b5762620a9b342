"""Closed-loop push-to-goal planning with frozen X-JEPA models (paper App. C "Closed-loop planning").

CEM over smooth two-knot action programs (16 actions linearly interpolated
between two 2-d knots), scored by the direct Δ=4 and Δ=16 heads. The default
cost (``PlanConfig.cost``, ``decoder``) decodes each predicted latent to an
object position with a ridge probe fit on privileged labels and scores the
decoded distance to the goal (Δ=16, plus half the Δ=4 distance). The field's
cost is ``goal_l2``: the goal observation (the arena with the object at the
goal) is encoded by the model's own encoder and a candidate scores
‖ẑ16 − z_goal‖² + 0.5 ‖ẑ4 − z_goal‖² (DINO-WM's and stable-worldmodel's LeWM
cost; ``goal_l1`` the L1 distance of V-JEPA 2-AC).
Replanning every 4 steps; the same planner, budget and environment for every
representation, plus a random controller.

Beside reach and improvement, every model gets a rank test (:func:`rank_test`): on a fixed set of candidate
programs from the episodes' fixed starts, how well its planning cost orders them like the true simulator's
cost (Spearman ρ and top-k overlap; :mod:`pokeworld.evaluate.ranking`). The planner only uses that order.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from .config import SEED, Limit, check_fields, from_preset, positive, to_dict
from .data import load, read_manifest
from .devices import pick_device
from .errors import ConfigError
from .evaluate.counterfactual import counterfactual_fit
from .evaluate.measure import EpisodeLatents, full_precision, position_decoder
from .evaluate.ranking import agreement
from .evaluate.state import encode_observations, model_device
from .io import check_outputs, save_figure, save_npz, save_text, write_json
from .model_inputs import checked_model
from .models.predictor import KVCache
from .preflight import require_finished_runs
from .published.paper import PLANNING
from .run_store import trained_store
from .rundir import finished_run_config, load_model
from .sim import PhysicsConfig, PokeWorldSim, physics as physics_kernels
from .sim.envs import vision_frames
from .sim.generate import generator_config
from .sim.policy import KNOT_SD, PROGRAM, programs

PLANNING_COSTS = ("goal_l2", "goal_l1", "decoder")
"""How a :class:`LatentScorer` turns predicted latents into a cost (``PlanConfig.cost``)."""
GOAL_FINGERS = ("behind", "current")
"""Where the goal observation draws the finger (``PlanConfig.goal_finger``)."""
PLANNING_HEADS = ("direct", "rollout")
"""How a :class:`LatentScorer` predicts a program's outcome (``PlanConfig.heads``)."""
COST_TERMS = ((16, 1.0), (4, 0.5))
"""The planning cost: Σ weight · ‖object position Δ steps into the program − goal‖ over (Δ, weight)."""
FINGER_BOX, OBJECT_BOX, GOAL_BOX = (0.15, 0.85), (0.25, 0.75), (0.15, 0.85)
"""Where episodes start the finger and the object, and where goals may lie (goals clear of the walls by more than
the object's radius, so every goal region can be reached)."""
FINGER_CLEARANCE = 0.25
"""Smallest start distance between finger and object centres (arena units)."""
UNIFORM_GOAL_BOX = (0.2, 0.8)
"""Where ``goals='uniform'`` draws goals: the released planner's box (its goals are uniform there, at least
``goal_distance`` from the object)."""
GOAL_DRAWS = ("fixed", "uniform")
"""How episodes place goals (``PlanConfig.goals``)."""
CANDIDATE_BATCH = 8192
"""Candidates whose last trunk step runs in one batch (:meth:`LatentScorer.latents`): bounds the memory of the
context's keys and values copied per candidate."""
MAX_GOAL_DISTANCE = 0.65
"""Largest ``goal_distance``: beyond it start/goal pairs crowd into opposite corners (2.5 % of uniform draws fit
the boxes at 0.65, 14 % at 0.55, 0.2 % at 0.75)."""


@dataclass
class PlanConfig:
    """Push-to-goal with CEM on trained runs."""

    out: str = "out/plan"
    """Output directory for plan.json and plan.md."""
    runs: tuple[str, ...] = ("runs/xjepa",)
    """Run directories (multi-horizon models with Δ=4 and Δ=16 heads) to plan with (default: where ``pokeworld
    train`` writes)."""
    data: str = ""
    """Dataset for fitting each model's position decoder (default: each run's training data)."""
    episodes: int = 50
    """Planning episodes (identical starts and goals for every controller)."""
    steps: int = 48
    """Control steps per episode."""
    replan: int = 4
    """Steps executed between replans."""
    population: int = 64
    """CEM candidates per iteration."""
    elites: int = 8
    """CEM elites."""
    iterations: int = 3
    """CEM iterations per replan."""
    context: int = 8
    """Observations of history fed to the model."""
    goal_radius: float = 0.1
    """A success is the object's centre entering this radius around the goal."""
    goal_distance: float = 0.55
    """Initial object-goal distance of every episode (the paper's example episode starts 0.55 from the goal;
    docs/design.md, "Planning: open-loop behaviour data and the rank test"); with ``goals='uniform'`` the
    smallest one."""
    goals: str = "fixed"
    """How goals are placed: 'fixed' — exactly ``goal_distance`` from the object in a random direction; 'uniform'
    — uniform in UNIFORM_GOAL_BOX², at least ``goal_distance`` from the object (the released planner's draw, with
    ``goal_distance`` 0.25: a median start distance near 0.36)."""
    settle: int = 0
    """Zero-action steps before control starts, so the first decision sees a full context (the released planner:
    16, its context length). Reach and improvement count from the first controlled step."""
    approach_weight: float = 0.0
    """Weight of the decoder cost's approach term: at each Δ of COST_TERMS, approach_weight · ‖decoded finger −
    push point‖, the push point ``approach_offset`` behind the decoded object on the far side from the goal
    (the released planner's cost: 0.4). It ranks candidates that bring the finger behind the object when none yet
    moves it, where the object-only cost ties; 0 scores the object alone (docs/design.md, "Planning: the
    approach term")."""
    approach_offset: float = 0.18
    """Distance of the push point behind the object (arena units; the released planner's 0.18, a finger and an
    object radius plus a margin)."""
    rank_topk: int = 8
    """k of the rank test's top-k overlap (of ``population`` candidates per start; chance k / population)."""
    cost: str = "decoder"
    """The planning cost (docs/design.md, "Planning: the cost"): 'decoder' (default) — the distance to the goal of
    the object position a ridge decoder, fit with privileged object labels, reads from ẑ_Δ; 'goal_l2' — Σ weight ·
    ‖ẑ_Δ − z_goal‖² over COST_TERMS, z_goal the model's own encoding of the goal observation (the field's cost:
    DINO-WM, LeWM's GoalMSE); 'goal_l1' — the same with the L1 distance (V-JEPA 2-AC). Measured: with perfect
    predictions the goal costs rank candidates at chance in these latents, the decoder cost does not."""
    goal_finger: str = "behind"
    """Where the goal observation draws the finger: 'behind' — touching the goal object on the far side from the
    finger's current position (where a push along that line leaves it), 'current' — where it is now. Its
    proprio holds that position at rest; its touch is zero (no contact)."""
    heads: str = "direct"
    """How a model predicts where a program sends the object: 'direct' (the paper's planner: the direct Δ = 4 / 16
    heads read the whole program at once) or 'rollout' (the Δ = 1 head composed step by step through the program,
    each prediction fed back into the predictor; docs/design.md, "Planning: open-loop behaviour data and the rank
    test")."""
    simulator_controller: bool = False
    """Also plan with the true simulator as the scorer (:class:`SimulatorScorer`): the same CEM with candidates
    ranked perfectly, the planner's ceiling on these starts. Runs may then be empty (``--runs`` with no value)."""
    seed: int = 0
    """Seed of starts, goals and CEM noise."""
    device: str = "auto"
    """Where each model predicts and its candidates are scored: 'auto' (cuda when available, else cpu), 'cpu', 'cuda'
    or 'cuda:N'. On CUDA the predicted latents are decoded and costed there (:meth:`LatentScorer.device_score`, TF32
    off), and only each CEM iteration's (episodes, population) costs come to the host; on the CPU the numpy decoder
    path is unchanged. Not part of a map's planning key."""

    LIMITS = {"episodes": Limit(1, 10**5), "steps": Limit(1, 10**4), "replan": Limit(1, PROGRAM),
              "population": Limit(1, 10**5), "elites": Limit(1, 10**5), "iterations": Limit(1, 1000),
              "context": Limit(1, 4096), "goal_radius": positive(MAX_GOAL_DISTANCE),
              "goal_distance": positive(MAX_GOAL_DISTANCE), "rank_topk": Limit(1, 10**5), "seed": SEED,
              "settle": Limit(0, 4096), "approach_weight": Limit(0, 100), "approach_offset": Limit(0, 1)}

    def __post_init__(self) -> None:
        check_fields(self)
        pick_device(self.device)  # a clear error now rather than inside torch later
        if self.elites > self.population or self.elites < 1:
            raise ConfigError("need 1 <= elites <= population")
        if self.replan < 1 or self.replan > PROGRAM:
            raise ConfigError(f"replan must be in [1, {PROGRAM}]")
        if not 0 < self.goal_distance <= MAX_GOAL_DISTANCE:
            raise ConfigError(f"goal_distance must be in (0, {MAX_GOAL_DISTANCE}] (objects start in {OBJECT_BOX}², "
                              f"goals lie in {GOAL_BOX}²), got {self.goal_distance}")
        if self.heads not in PLANNING_HEADS:
            raise ConfigError(f"heads must be one of {list(PLANNING_HEADS)}, got {self.heads!r}")
        if self.cost not in PLANNING_COSTS:
            raise ConfigError(f"cost must be one of {list(PLANNING_COSTS)}, got {self.cost!r}")
        if self.goal_finger not in GOAL_FINGERS:
            raise ConfigError(f"goal_finger must be one of {list(GOAL_FINGERS)}, got {self.goal_finger!r}")
        if self.goals not in GOAL_DRAWS:
            raise ConfigError(f"goals must be one of {list(GOAL_DRAWS)}, got {self.goals!r}")
        if self.approach_weight and self.cost != "decoder":
            raise ConfigError(f"approach_weight applies to the decoder cost (cost='decoder'), got cost={self.cost!r}; "
                              "set --approach-weight 0 with the goal costs")
        if not 1 <= self.rank_topk <= self.population:
            raise ConfigError(f"rank_topk must be in [1, population={self.population}], got {self.rank_topk}")
        counts = {"episodes": self.episodes, "steps": self.steps, "iterations": self.iterations,
                  "context": self.context}
        bad_counts = {k: v for k, v in counts.items() if v < 1}
        if bad_counts:
            raise ConfigError(f"episodes, steps, iterations and context must be ≥ 1, got {bad_counts}")
        # a goal radius of goal_distance or more counts every episode a success before it moves; NaN fails too
        if not 0 < self.goal_radius < self.goal_distance or self.seed < 0:
            raise ConfigError(f"goal_radius must be in (0, goal_distance={self.goal_distance}) and seed ≥ 0, got "
                              f"goal_radius={self.goal_radius}, seed={self.seed}")


RELEASED_PLANNER = {"episodes": 100, "steps": 64, "context": 16, "settle": 16, "population": 256, "elites": 32,
                    "iterations": 3, "goal_radius": 0.12, "goals": "uniform", "goal_distance": 0.25,
                    "approach_weight": 0.4, "approach_offset": 0.18}
"""The planner behind the paper's Table "planning", as the authors' released code runs it
(``exp/e003_motion/plan_eval.py``): the ``paper`` preset."""
PRESETS = {"tiny": {"episodes": 3, "steps": 8, "population": 8, "elites": 2, "iterations": 1, "rank_topk": 2},
           "cpu": {}, "paper": RELEASED_PLANNER}


def make_config(preset: str = "cpu", **overrides) -> PlanConfig:
    return from_preset(PlanConfig, PRESETS, preset, **overrides)


class LatentScorer:
    """Scores action programs with one model's direct heads: against its encoding of the goal observation
    (``cost`` 'goal_l2' / 'goal_l1') or through its position decoder ('decoder'). The decoder is fit either way:
    the rank test's diagnostics read predicted latents as positions through it.

    The model runs on ``device``. On CUDA the decoder cost stays there (:meth:`device_score`: the fitted ridge as one
    affine map on the latents' device, the costs computed beside it); on the CPU it is the numpy decoder path, and
    :meth:`device_positions` / :meth:`device_score` are the device path run on the CPU (equal to float rounding)."""

    def __init__(self, run_dir: str, data: str, heads: str = "direct", cost: str = "decoder",
                 goal_finger: str = "behind", physics: PhysicsConfig | None = None, device: str = "cpu",
                 approach: tuple[float, float] = (0.0, 0.18)):
        """``approach``: (weight, offset) of the decoder cost's approach term (``PlanConfig.approach_weight`` /
        ``approach_offset``); with a weight, a second decoder reads the finger position."""
        if heads not in PLANNING_HEADS:
            raise ConfigError(f"heads must be one of {list(PLANNING_HEADS)}, got {heads!r}")
        if cost not in PLANNING_COSTS:
            raise ConfigError(f"cost must be one of {list(PLANNING_COSTS)}, got {cost!r}")
        self.heads, self.cost, self.goal_finger, self.approach = heads, cost, goal_finger, approach
        self.physics = physics or PhysicsConfig()
        self._goal: tuple[dict, np.ndarray, torch.Tensor] | None = None  # (history, goal, goal latents)
        self.model = load_model(run_dir, map_location=pick_device(device))
        if not {4, 16} <= set(self.model.horizons):
            raise ConfigError(f"{run_dir}: planning needs Δ=4 and Δ=16 heads, model has {self.model.horizons}")
        if not data:
            data = trained_store(run_dir, "plan")  # the run's own store, found by its recorded content hash
        ds = load(data)
        fit = ds.episodes("probe_fit")
        lat = EpisodeLatents(self.model, ds, fit, 64)
        self.decoder = position_decoder(ds, lat, fit, np.random.default_rng(0))
        self.finger_decoder = (position_decoder(ds, lat, fit, np.random.default_rng(0), "finger_pos")
                               if approach[0] else None)
        # the same decoders as float64 weights on the model's device, their standardisation folded in: predicted
        # latents are decoded where they are computed
        dev = model_device(self.model)
        self.decoder_affine, self.finger_affine = (
            None if d is None else tuple(torch.as_tensor(a, dtype=torch.float64, device=dev) for a in d.affine())
            for d in (self.decoder, self.finger_decoder))
        self._encoded: tuple[dict, torch.Tensor] | None = None  # (history, its latents): one encode per replan

    @property
    def on_device(self) -> bool:
        """Whether decoder costs are computed on the model's device (:meth:`device_score`): a CUDA model."""
        return model_device(self.model).type == "cuda"

    def positions(self, hist: dict, cand: np.ndarray) -> dict[int, np.ndarray]:
        """hist: frames (E, C, H, W), proprio, touch (E, C, .), actions (E, C-1, 2); cand (E, P, 16, 2) ->
        {Δ: (E, P, 2) decoded object position Δ steps into each program} for the Δ of COST_TERMS."""
        objects = self.decoded(hist, cand, self.on_device)[0]
        return {d: p.cpu().numpy() if isinstance(p, torch.Tensor) else p for d, p in objects.items()}

    def device_positions(self, hist: dict, cand: np.ndarray) -> dict[int, torch.Tensor]:
        """:meth:`positions` as float64 tensors on the model's device: the latents never leave it."""
        return self.decoded(hist, cand, on_device=True)[0]

    @torch.no_grad()
    def decoded(self, hist: dict, cand: np.ndarray, on_device: bool) -> tuple[dict, dict | None]:
        """({Δ: (E, P, 2) decoded object positions}, the same for the finger or None without the approach term),
        both from one prediction of the latents: float64 tensors where the model is (the decoders as affine maps)
        with ``on_device``, else numpy through the decoders themselves."""
        E, P = cand.shape[:2]
        lat = self.latents(hist, cand)
        if on_device:
            read = lambda ab: {d: (z.double() @ ab[0] + ab[1]).reshape(E, P, -1) for d, z in lat.items()}  # noqa: E731
            affines = (self.decoder_affine, self.finger_affine)
        else:
            lat = {d: z.float().cpu().numpy() for d, z in lat.items()}
            read = lambda dec: {d: dec.predict(z).reshape(E, P, 2) for d, z in lat.items()}  # noqa: E731
            affines = (self.decoder, self.finger_decoder)
        return read(affines[0]), None if affines[1] is None else read(affines[1])

    def device_score(self, hist: dict, cand: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """The decoder cost of :meth:`score`, computed on the model's device; the (E, P) costs are the one copy to
        the host."""
        objects, fingers = self.decoded(hist, cand, on_device=True)
        g = torch.as_tensor(goal, dtype=torch.float64, device=self.decoder_affine[0].device)
        return decoded_cost(objects, g, fingers, *self.approach).cpu().numpy()

    @torch.no_grad()
    def latents(self, hist: dict, cand: np.ndarray) -> dict[int, torch.Tensor]:
        """The predicted latents {Δ: (E·P, D)} Δ steps into each program (``hist`` and ``cand`` as in
        :meth:`positions`), for the Δ of COST_TERMS."""
        E, P = cand.shape[:2]
        m = self.model
        # the history is the same for every CEM iteration of a replan (control() builds it once), so its
        # frames are encoded once, not once per iteration
        if self._encoded is None or self._encoded[0] is not hist:
            self._encoded = (hist, m.encode(hist["frames"], hist["proprio"], hist["touch"]))  # (E, C, D)
        z = self._encoded[1]
        C = z.shape[1]
        acts = cand.reshape(E * P, PROGRAM, 2).astype(np.float32)
        if self.heads == "rollout" or m.tokens:
            zc = z[:, None].expand(E, P, *z.shape[1:]).reshape(E * P, *z.shape[1:])
            past = np.repeat(hist["actions"][:, None], P, 1).reshape(E * P, C - 1, 2).astype(np.float32)
            if self.heads == "rollout":  # z at C .. C+15: the latent after each of the program's 16 actions
                zr = m.rollout(zc, acts, PROGRAM, actions_context=past)
                return {delta: zr[:, delta - 1] for delta, _ in COST_TERMS}
            h = m.trunk(zc, np.concatenate([past, cand[:, :, 0].reshape(E * P, 1, 2)], 1).astype(np.float32))
            return {delta: m.predict(h[:, -1:], acts, delta)[:, 0] for delta, _ in COST_TERMS}
        return direct_latents(m, z, hist["actions"], cand)

    @torch.no_grad()
    def goal_latents(self, hist: dict, goal: np.ndarray) -> torch.Tensor:
        """(E, D): the model's encoding of each episode's goal observation (:func:`goal_observation`, the finger
        placed from the history's last proprio), computed once per replan."""
        if self._goal is None or self._goal[0] is not hist or self._goal[1] is not goal:
            obs = goal_observation(self.physics, hist["proprio"][:, -1, :2], goal, self.goal_finger)
            z = self.model.encode(vision_frames(obs["vision"])[:, None], obs["proprio"][:, None], obs["touch"][:, None])[:, 0]
            self._goal = (hist, goal, z)
        return self._goal[2]

    def goal_cost(self, latents: dict[int, torch.Tensor], z_goal: torch.Tensor) -> np.ndarray:
        """{Δ: (E·P, D)} predicted (or true) latents and (E, D) goal latents -> (E, P) cost (``cost``)."""
        E = z_goal.shape[0]
        total = 0.0
        for d, w in COST_TERMS:
            diff = latents[d].float().reshape(E, -1, z_goal.shape[-1]) - z_goal.float()[:, None]
            dist = diff.abs().sum(-1) if self.cost == "goal_l1" else diff.pow(2).sum(-1)
            total = total + w * dist
        return total.cpu().numpy()

    def decode(self, obs: dict) -> np.ndarray:
        """Observations (N, ...) -> (N, 2): the object position this model's encoder and decoder read from them
        (what a perfect head's prediction would decode to: the rank test's decoder control)."""
        return self.decoder.predict(encode_observations(self.model, obs))

    def score(self, hist: dict, cand: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """(E, P) planning cost of ``cand`` (COST_TERMS): against the encoded goal, or of decoded positions
        (:func:`decoded_cost`, with the approach term when ``approach`` has a weight)."""
        if self.cost == "decoder" and self.on_device:
            return self.device_score(hist, cand, goal)
        if self.cost == "decoder":
            objects, fingers = self.decoded(hist, cand, on_device=False)
            return decoded_cost(objects, goal, fingers, *self.approach)
        return self.goal_cost(self.latents(hist, cand), self.goal_latents(hist, goal))

    @torch.no_grad()
    def true_goal_cost(self, hist: dict, observations: dict[int, dict], goal: np.ndarray) -> np.ndarray:
        """The goal cost of the *true* observations Δ steps into each program ({Δ: observations (E·P, ...)}),
        encoded by this model: how the cost ranks when the heads' predictions are perfect (the rank test's
        goal control, the counterpart of the decoder control)."""
        z = {d: self.model.encode(vision_frames(o["vision"])[:, None], o["proprio"][:, None], o["touch"][:, None])[:, 0]
             for d, o in observations.items()}
        return self.goal_cost(z, self.goal_latents(hist, goal))


@torch.no_grad()
def direct_latents(model, z: torch.Tensor, past: np.ndarray, cand: np.ndarray) -> dict[int, torch.Tensor]:
    """A global-latent model's direct-head predictions {Δ: (E·P, D)} for the Δ of COST_TERMS, from a history's
    latents z (E, C, D), its past actions (E, C-1, 2) and candidate programs (E, P, 16, 2).

    Equal to running the trunk over the whole context once per candidate (its last state reads the program's
    first action), at a fraction of the cost: the context before the last observation is the same for every
    candidate, so its keys and values are computed once per episode and copied to the candidates, which then feed
    only the last observation with their first action."""
    E, P = cand.shape[:2]
    C = z.shape[1]
    out: dict[int, list[torch.Tensor]] = {d: [] for d, _ in COST_TERMS}
    step = max(1, CANDIDATE_BATCH // P)  # episodes per batch
    for s in range(0, E, step):
        n = min(step, E - s)
        cache = KVCache()
        if C > 1:
            model.trunk(z[s:s + n, :C - 1], np.asarray(past[s:s + n], np.float32), cache)
            cache.k = [k.repeat_interleave(P, 0) for k in cache.k]
            cache.v = [v.repeat_interleave(P, 0) for v in cache.v]
        progs = cand[s:s + n].reshape(n * P, PROGRAM, 2).astype(np.float32)
        h = model.trunk(z[s:s + n, C - 1:].repeat_interleave(P, 0), progs[:, :1], cache)  # (n·P, 1, width)
        for d, _ in COST_TERMS:
            out[d].append(model.predict(h, progs, d)[:, 0])
    return {d: torch.cat(v) for d, v in out.items()}


def goal_observation(physics: PhysicsConfig, finger: np.ndarray, goal: np.ndarray, where: str = "behind") -> dict:
    """Observations (E, ...) of the goal: the arena with the object's centre at ``goal`` (E, 2) and the finger at
    ``finger`` (E, 2, its current position) or, ``where='behind'``, touching the object on the far side from it
    (the finger's approach line continued through the goal). Proprio: that position at rest; touch: zero."""
    fp = np.asarray(finger, float)
    if where == "behind":
        away = np.asarray(goal, float) - fp
        away /= np.maximum(np.linalg.norm(away, axis=1, keepdims=True), 1e-9)
        fp = goal - (physics.finger_radius + physics.object_radius) * away
    lo, hi = physics.finger_radius, physics.arena - physics.finger_radius
    fp = np.clip(fp, lo, hi)
    state = np.zeros((len(fp), 8))
    state[:, 0:2], state[:, 4:6] = fp, goal
    size = physics.image_size
    frames = np.zeros((len(fp), size, size), np.uint8)
    physics_kernels.render_kernel(state, frames, physics.finger_radius, physics.object_radius, physics.arena,
                                  physics.object_intensity, physics.finger_intensity)
    return {"vision": frames[..., None], "proprio": np.concatenate([fp, np.zeros_like(fp)], 1).astype(np.float32),
            "touch": np.zeros((len(fp), physics_kernels.TOUCH_DIM), np.float32)}


class SimulatorScorer:
    """Scores action programs by the planning cost of the true outcome: copies of the live simulator's state and
    hidden parameters are rolled through every candidate (the oracle a model's scores are ranked against)."""

    def __init__(self, sim: PokeWorldSim, approach: tuple[float, float] = (0.0, 0.18)):
        """``approach``: (weight, offset) of the cost's approach term, as :class:`LatentScorer`'s."""
        self.sim, self.approach = sim, approach

    def replica(self, cand: np.ndarray, render: bool = False) -> tuple[PokeWorldSim, np.ndarray]:
        """One copy of the live simulator per candidate, and the candidates as (E·P, 16, 2). The dynamics read
        only state, parameters and actions (noise enters the touch sensor alone), so a copy rolls out exactly as
        the live simulator would; without ``render`` its frames are never drawn, so they are kept tiny."""
        sim, (E, P) = self.sim, cand.shape[:2]
        b = PokeWorldSim(E * P, sim.cfg if render else replace(sim.cfg, image_size=8), seed=0)
        b.state[:], b.params[:] = np.repeat(sim.state, P, 0), np.repeat(sim.params, P, 0)
        return b, cand.reshape(E * P, PROGRAM, 2)

    def rollout(self, cand: np.ndarray, finger: bool = False):
        """cand (E, P, 16, 2) -> (E, P, 17, 2): the object's true positions before and after every action; with
        ``finger``, (object, finger) positions."""
        (E, P), (b, acts) = cand.shape[:2], self.replica(cand)
        pos, fpos = [b.state[:, 4:6].copy()], [b.state[:, 0:2].copy()]
        for t in range(PROGRAM):
            b.step(acts[:, t], render=False)
            pos.append(b.state[:, 4:6].copy())
            fpos.append(b.state[:, 0:2].copy())
        paths = tuple(np.stack(p, 1).reshape(E, P, PROGRAM + 1, 2) for p in (pos, fpos))
        return paths if finger else paths[0]

    def end_observations(self, cand: np.ndarray) -> dict:
        """cand (E, P, 16, 2) -> the true observations after each whole program, flattened to (E·P, ...)."""
        return self.observations_at(cand, (PROGRAM,))[PROGRAM]

    def observations_at(self, cand: np.ndarray, deltas) -> dict[int, dict]:
        """cand (E, P, 16, 2) -> {Δ: the true observations Δ actions into each program, flattened to (E·P, ...)}."""
        b, acts = self.replica(cand, render=True)
        out = {}
        for t in range(max(deltas)):
            obs = b.step(acts[:, t], render=t + 1 in deltas)
            if t + 1 in deltas:
                out[t + 1] = obs
        return out

    def score(self, hist: dict, cand: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """cand (E, P, 16, 2), goal (E, 2) -> (E, P) planning cost; ``hist`` is unused (the state is known)."""
        path, finger_path = self.rollout(cand, finger=True)
        return cost(path, goal, finger_path, self.approach)


def cost(path: np.ndarray, goal: np.ndarray, finger_path: np.ndarray | None = None,
         approach: tuple[float, float] = (0.0, 0.18)) -> np.ndarray:
    """Object positions (E, P, 17, 2) along candidate programs -> (E, P) planning cost (:func:`decoded_cost`); with
    an ``approach`` weight, the finger positions ``finger_path`` (same shape) enter through the approach term."""
    at = lambda p: None if p is None else {d: p[:, :, d] for d, _ in COST_TERMS}  # noqa: E731
    return decoded_cost(at(path), goal, at(finger_path), *approach)


def decoded_cost(objects: dict, goal, fingers: dict | None = None, weight: float = 0.0, offset: float = 0.18):
    """The planning cost of COST_TERMS: Σ over (Δ, w) of w · (‖object_Δ − goal‖ + weight · ‖finger_Δ − push
    point_Δ‖), the push point ``offset`` behind object_Δ on the far side from the goal (PlanConfig.approach_weight).

    ``objects`` / ``fingers``: {Δ: (E, P, 2)} positions, numpy arrays or tensors (then ``goal`` (E, 2) is a tensor
    on their device); returns (E, P) of the same kind. Without ``weight`` the fingers are not read."""
    norm = lambda x: (x * x).sum(-1) ** 0.5  # noqa: E731  (numpy and torch alike)
    total = 0.0
    for d, w in COST_TERMS:
        obj, g = objects[d], goal[:, None]
        term = norm(obj - g)
        if weight:
            away = (obj - g) / (term[..., None] + 1e-8)
            term = term + weight * norm(fingers[d] - (obj + offset * away))
        total = total + w * term
    return total


def episode_setup(cfg: PlanConfig) -> dict:
    """Starts and goals: finger anywhere clear of the walls, the object 0.25 or more from it, the goal exactly
    ``goal_distance`` from the object in a random direction. Object and direction are redrawn together until
    the goal lies inside GOAL_BOX: clipping it there instead would shorten the distance. With ``goals='uniform'``
    the goal is uniform in UNIFORM_GOAL_BOX², redrawn until ``goal_distance`` or more from the object."""
    rng = np.random.default_rng(cfg.seed)
    n = cfg.episodes
    fp = rng.uniform(*FINGER_BOX, (n, 2))
    op = rng.uniform(*OBJECT_BOX, (n, 2))
    if cfg.goals == "uniform":
        return uniform_goals(rng, fp, op, cfg.goal_distance)
    goal = np.full((n, 2), np.nan)
    for _ in range(1000):
        outside = ~np.all((goal >= GOAL_BOX[0]) & (goal <= GOAL_BOX[1]), 1)
        bad = outside | (np.linalg.norm(op - fp, axis=1) < FINGER_CLEARANCE)
        if not bad.any():
            break
        m = int(bad.sum())
        op[bad] = rng.uniform(*OBJECT_BOX, (m, 2))
        ang = rng.uniform(0, 2 * np.pi, m)
        goal[bad] = op[bad] + cfg.goal_distance * np.stack([np.cos(ang), np.sin(ang)], 1)
    else:
        raise ConfigError(f"no start/goal pair {cfg.goal_distance} apart found for {int(bad.sum())} episodes")
    return {"finger_pos": fp, "object_pos": op, "goal": goal, "sim_seed": int(rng.integers(2**31))}


def uniform_goals(rng: np.random.Generator, fp: np.ndarray, op: np.ndarray, min_distance: float) -> dict:
    """:func:`episode_setup` for ``goals='uniform'``: objects redrawn until 0.25 or more from the finger, goals
    uniform in UNIFORM_GOAL_BOX² redrawn until ``min_distance`` or more from the object."""
    n = len(fp)
    goal = rng.uniform(*UNIFORM_GOAL_BOX, (n, 2))
    for _ in range(1000):
        near_finger = np.linalg.norm(op - fp, axis=1) < FINGER_CLEARANCE
        op[near_finger] = rng.uniform(*OBJECT_BOX, (int(near_finger.sum()), 2))
        near_goal = np.linalg.norm(goal - op, axis=1) < min_distance
        goal[near_goal] = rng.uniform(*UNIFORM_GOAL_BOX, (int(near_goal.sum()), 2))
        if not (near_finger.any() or near_goal.any()):
            break
    else:
        raise ConfigError(f"no goal {min_distance} or more from its object found for some episodes")
    return {"finger_pos": fp, "object_pos": op, "goal": goal, "sim_seed": int(rng.integers(2**31))}


def start_sim(cfg: PlanConfig, setup: dict) -> tuple[PokeWorldSim, dict]:
    """The planning environment at the episodes' starts (the same hidden parameters for every controller), with
    the physics of the planned runs' corpus (``setup["physics"]``, :func:`planning_physics`) when set."""
    sim = PokeWorldSim(cfg.episodes, setup.get("physics") or PhysicsConfig(), seed=setup["sim_seed"])
    return sim, sim.reset(finger_pos=setup["finger_pos"], object_pos=setup["object_pos"])


def rank_candidates(cfg: PlanConfig) -> np.ndarray:
    """(episodes, population, 16, 2): the rank test's fixed candidates, drawn like the CEM's first proposal at
    every replan (knots ~ N(0, KNOT_SD²)) from a stream of their own, so every controller ranks the same ones."""
    rng = np.random.default_rng([cfg.seed, 2])
    return programs(rng.normal(0.0, KNOT_SD, (cfg.episodes, cfg.population, 4)))


def rank_test(cfg: PlanConfig, setup: dict, scorer) -> dict:
    """How well ``scorer`` orders the fixed candidates from every episode's start like the true simulator.

    The model sees what the planner sees at its first replan (one observation, no past actions). Returns
    :func:`pokeworld.evaluate.ranking.agreement` plus ``moved``: the share of candidates whose true rollout moves
    the object (the rest tie at the start distance, which bounds how much of the order is decidable). A scorer
    with a ``positions`` method (:class:`LatentScorer`) also gets :func:`~pokeworld.evaluate.counterfactual.
    counterfactual_fit` of its Δ = 16 positions (``spread_ratio``, ``within_r2``, the displacements it predicts
    on misses and hits): why its order is what it is; with a ``decode`` method, the same fit of the true end
    frames read through the model's encoder and decoder (``decoded_truth_*``), which tells a head that predicts
    phantom pushes from a decoder that reads them into frames where nothing moved.
    """
    sim, obs = start_sim(cfg, setup)
    hist = {"frames": vision_frames(obs["vision"])[:, None], "proprio": obs["proprio"][:, None], "touch": obs["touch"][:, None],
            "actions": np.zeros((cfg.episodes, 0, 2), np.float32)}
    cand, goal = rank_candidates(cfg), setup["goal"]
    path, finger_path = SimulatorScorer(sim).rollout(cand, finger=True)
    truth = cost(path, goal, finger_path, approach_of(cfg))
    model = np.asarray(scorer.score(hist, cand, goal), float)
    moved = (path != path[:, :, :1]).any(-1).any(-1)  # an untouched object at rest stays exactly where it was
    out = agreement(model, truth, cfg.rank_topk) | {"moved": float(moved.mean())}
    if hasattr(scorer, "positions"):
        fit = counterfactual_fit(scorer.positions(hist, cand)[PROGRAM], path[:, :, PROGRAM], path[:, 0, 0])
        out |= {k: fit[k] for k in COUNTERFACTUAL_METRICS}
    if hasattr(scorer, "decode"):  # the same fit for the true end frames read through the model's own decoder
        seen = SimulatorScorer(sim).observations_at(cand, [d for d, _ in COST_TERMS])
        decoded = scorer.decode(seen[PROGRAM]).reshape(path[:, :, PROGRAM].shape)
        fit = counterfactual_fit(decoded, path[:, :, PROGRAM], path[:, 0, 0])
        out |= {f"decoded_truth_{k}": fit[k] for k in COUNTERFACTUAL_METRICS}
        if getattr(scorer, "cost", "decoder") != "decoder":  # the goal cost of the true future, encoded
            control_rank = agreement(scorer.true_goal_cost(hist, seen, goal), truth, cfg.rank_topk)
            out |= {f"goal_truth_{k}": control_rank[k] for k in ("spearman", "topk_overlap")}
    return out


def control(cfg: PlanConfig, setup: dict, scorer: LatentScorer | None, simulator: bool = False) -> dict:
    """Run every episode with CEM on ``scorer`` (random actions when None; the live simulator's own
    :class:`SimulatorScorer` when ``simulator``); returns distances over time."""
    n = cfg.episodes
    sim, obs = start_sim(cfg, setup)
    if simulator:
        scorer = SimulatorScorer(sim, approach_of(cfg))
    rng = np.random.default_rng(cfg.seed + 1)
    goal = setup["goal"]
    hist = settled_history(cfg, sim, obs)
    dist = [np.linalg.norm(sim.state[:, 4:6] - goal, axis=1)]
    obj_path, finger_path = [sim.state[:, 4:6].copy()], [sim.state[:, 0:2].copy()]
    plan = np.zeros((n, PROGRAM, 2))
    for t in range(cfg.steps):
        k = t % cfg.replan
        if k == 0:
            if scorer is None:
                plan = rng.uniform(-1, 1, (n, PROGRAM, 2))
            else:
                c = cfg.context
                h = {key: np.stack(v[-c:], 1) for key, v in hist.items() if key != "actions"}
                past = hist["actions"][-(h["frames"].shape[1] - 1):] if h["frames"].shape[1] > 1 else []
                h["actions"] = np.stack(past, 1) if len(past) else np.zeros((n, 0, 2), np.float32)
                mu, sd = np.zeros((n, 4)), np.full((n, 4), KNOT_SD)
                for _ in range(cfg.iterations):
                    knots = mu[:, None] + sd[:, None] * rng.normal(size=(n, cfg.population, 4))
                    cand = programs(knots)
                    scores = scorer.score(h, cand, goal)
                    elite = np.argsort(scores, 1)[:, :cfg.elites]
                    ek = np.take_along_axis(knots, elite[..., None], 1)
                    mu, sd = ek.mean(1), ek.std(1) + 0.05
                plan = programs(mu)
        a = plan[:, k]
        obs = sim.step(a)
        hist["frames"].append(vision_frames(obs["vision"]))
        hist["proprio"].append(obs["proprio"])
        hist["touch"].append(obs["touch"])
        hist["actions"].append(a.astype(np.float32))
        dist.append(np.linalg.norm(sim.state[:, 4:6] - goal, axis=1))
        obj_path.append(sim.state[:, 4:6].copy())
        finger_path.append(sim.state[:, 0:2].copy())
    d = np.stack(dist, 1)
    paths = np.stack(obj_path, 1)
    return episode_metrics(d, paths, cfg.goal_radius) | {
        "distance": d, "finger_final": sim.state[:, 0:2].copy(), "object_path": paths,
        "finger_path": np.stack(finger_path, 1)}


def settled_history(cfg: PlanConfig, sim: PokeWorldSim, obs: dict) -> dict:
    """The history a controller starts from: the start observation and ``cfg.settle`` zero-action steps (so the
    first decision can see a full context; the metrics start after them). Lists per key, grown as control runs."""
    hist = {"frames": [vision_frames(obs["vision"])], "proprio": [obs["proprio"]], "touch": [obs["touch"]],
            "actions": []}
    for _ in range(cfg.settle):
        obs = sim.step(np.zeros((sim.n, 2)))
        for key, value in (("frames", vision_frames(obs["vision"])), ("proprio", obs["proprio"]),
                           ("touch", obs["touch"]), ("actions", np.zeros((sim.n, 2), np.float32))):
            hist[key].append(value)
    return hist


def approach_of(cfg: PlanConfig) -> tuple[float, float]:
    """(weight, offset) of ``cfg``'s approach term, as the scorers take it."""
    return cfg.approach_weight, cfg.approach_offset


def episode_metrics(dist: np.ndarray, object_path: np.ndarray, goal_radius: float) -> dict:
    """:data:`METRICS` from object-goal distances (E, T+1) and object paths (E, T+1, 2) of a controller's episodes."""
    # the median improvement is exactly 0 whenever most episodes never touch the object; the mean and the
    # share of episodes whose object moved say whether that is what happened
    moved = np.linalg.norm(object_path - object_path[:, :1], axis=-1).max(1) > 0.01
    return {"reach": float((dist.min(1) < goal_radius).mean()),
            "median_improvement": float(np.median(dist[:, 0] - dist[:, -1])),
            "median_closest_improvement": float(np.median(dist[:, 0] - dist.min(1))),
            "mean_improvement": float(np.mean(dist[:, 0] - dist[:, -1])), "object_moved": float(moved.mean())}


METRICS = ("reach", "median_improvement", "median_closest_improvement", "mean_improvement", "object_moved")
"""Per-controller planning metrics (:func:`control`): reach (the object's centre ever within ``goal_radius``),
the start distance minus the final one (``median_improvement``) and minus the closest one
(``median_closest_improvement``: the released planner's "median improvement", the paper's column)."""
COUNTERFACTUAL_METRICS = ("spread_ratio", "within_r2", "miss_displacement", "hit_displacement",
                          "hit_true_displacement")
"""Per-model counterfactual fit of the rank test's Δ = 16 positions (:mod:`pokeworld.evaluate.counterfactual`)."""
RANK_METRICS = ("spearman", "topk_overlap", "topk_chance", "moved", *COUNTERFACTUAL_METRICS,
                *(f"decoded_truth_{k}" for k in COUNTERFACTUAL_METRICS), "goal_truth_spearman",
                "goal_truth_topk_overlap")
"""Per-model rank-test metrics (:func:`rank_test`); None for the random controller, which scores nothing."""

PAPER = PLANNING
"""Paper Table "planning": controller -> (goal-region reach, median distance improvement)."""


def plan_runs(cfg: PlanConfig, runs: dict[str, list[str]], data: str = "") -> dict:
    """Plan with every run and with the random controller on one shared start/goal set.

    ``runs`` maps a controller label (e.g. a variant) to its run directories (seeds); a label's metrics are the
    means over its runs (per-run values under ``per_run``): METRICS from planning and RANK_METRICS from the rank
    test of the same scorer (:func:`rank_test`). Returns ``{"summary": {label: {*METRICS, *RANK_METRICS,
    "per_run"}}, "episodes": {label: control output of its first run}, "setup": episode_setup(cfg)}``; ``data``
    overrides each run's decoder-fit corpus.
    """
    setup = episode_setup(cfg) | {"physics": planning_physics(runs, data or cfg.data)}
    episodes = {"random": control(cfg, setup, None)}
    summary = {"random": {k: episodes["random"][k] for k in METRICS} | dict.fromkeys(RANK_METRICS) | {"per_run": {}}}
    if cfg.simulator_controller:  # the ceiling: its rank test would be the simulator against itself, so none
        episodes["simulator"] = control(cfg, setup, None, simulator=True)
        summary["simulator"] = ({k: episodes["simulator"][k] for k in METRICS} | dict.fromkeys(RANK_METRICS)
                                | {"per_run": {}})
        print(f"[plan] simulator: reach {summary['simulator']['reach']:.0%}, "
              f"median improvement {summary['simulator']['median_improvement']:+.3f}")
    for label, dirs in runs.items():
        per = {}
        for r in dirs:
            scorer = LatentScorer(r, data or cfg.data, cfg.heads, cfg.cost, cfg.goal_finger, setup["physics"],
                                  cfg.device, approach_of(cfg))
            # fp32 on CUDA (no TF32), so a GPU ranks candidates as the CPU does, to float rounding
            with full_precision(pick_device(cfg.device)):
                started = time.perf_counter()
                res = control(cfg, setup, scorer)
                res["seconds_per_decision"] = (time.perf_counter() - started) / -(-cfg.steps // cfg.replan)
                rank = rank_test(cfg, setup, scorer)
            episodes.setdefault(label, res)
            per[Path(r).name] = ({k: res[k] for k in METRICS} | {k: rank.get(k, float("nan")) for k in RANK_METRICS}
                                 | {"seconds_per_decision": res["seconds_per_decision"]})
            print(f"[plan] {label} ({Path(r).name}): reach {res['reach']:.0%}, median improvement to the closest "
                  f"approach {res['median_closest_improvement']:+.3f} / to the end {res['median_improvement']:+.3f}, "
                  f"rank ρ {rank['spearman']:+.2f}, "
                  f"top-{cfg.rank_topk} overlap {rank['topk_overlap']:.2f} (chance {rank['topk_chance']:.2f}), "
                  f"Δ=16 spread ratio {rank.get('spread_ratio', float('nan')):.2f}, "
                  f"within-start R² {rank.get('within_r2', float('nan')):+.2f}, predicted displacement on "
                  f"misses {rank.get('miss_displacement', float('nan')):.3f} / on hits "
                  f"{rank.get('hit_displacement', float('nan')):.3f} "
                  f"(true {rank.get('hit_true_displacement', float('nan')):.3f}); the true end frames decoded: "
                  f"misses {rank.get('decoded_truth_miss_displacement', float('nan')):.3f}, within-start R² "
                  f"{rank.get('decoded_truth_within_r2', float('nan')):+.2f}")
        summary[label] = {k: float(np.mean([v[k] for v in per.values()])) for k in (*METRICS, *RANK_METRICS)}
        summary[label]["seconds_per_decision"] = float(np.mean([v["seconds_per_decision"] for v in per.values()]))
        summary[label]["per_run"] = per
    return {"summary": summary, "episodes": episodes, "setup": setup}


def planning_physics(runs: dict[str, list[str]], data: str = "") -> PhysicsConfig:
    """The arena the runs were trained in: the physics of their corpus (``data``, else each run's own), read from
    the store's manifest as what it was made with (:func:`pokeworld.sim.generate.generator_config`); the default
    physics for a store that is not a PokeWorld corpus or when there is no run. Runs from corpora of different
    physics are refused: their reach would be measured in different environments."""
    found = {}
    for r in (r for dirs in runs.values() for r in dirs):
        store = data or trained_store(r, "plan")  # found by its recorded content hash, not relative to here
        manifest = read_manifest(store)
        if manifest.get("generator") == "pokeworld.sim.generate":
            found[r] = generator_config(manifest).physics
    kinds = {repr(p) for p in found.values()}
    if len(kinds) > 1:
        raise ConfigError(f"the runs were trained on corpora of different physics ({', '.join(map(str, found))}); "
                          "plan them separately (each in its own arena)")
    return next(iter(found.values())) if found else PhysicsConfig()


def showcase_episode(episodes: dict, left: str, right: str) -> int:
    """The held-out episode the figure shows: the one where ``right`` beats ``left`` by the largest final
    object-goal distance (a fixed rule, so the figure is not hand-picked)."""
    gain = episodes[left]["distance"][:, -1] - episodes[right]["distance"][:, -1]
    return int(np.argmax(gain))


def controller_words(label: str) -> str:
    """What a controller of the plan figure plans with, in words."""
    return {"simulator": "the simulator's own scores", "random": "random programs"}.get(
        label, f"{label}'s frozen latent")


def figure(planned: dict, out: Path, goal_radius: float, left: str | None = None,
           right: str | None = None) -> list[Path]:
    """The paper's plan figure: one held-out episode under two representations, plus both distance curves; with
    one planned representation (``pokeworld plan --runs RUN``), that run's episode panel and its distance curve
    beside the random controller's.

    ``left`` / ``right`` default to the first and last planned representation (e.g. V and VFX); a single one (or
    ``left == right``) draws one panel.
    """
    import textwrap

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    eps = planned["episodes"]
    labels = ([k for k in eps if k not in ("random", "simulator")] or [k for k in eps if k != "random"]
              or ["random"])
    left, right = left or labels[0], right or labels[-1]
    shown = [left] if left == right else [left, right]
    if len(shown) == 2:
        i = showcase_episode(eps, left, right)
        rule = f"the episode where {right} ends nearest the goal relative to {left}"
    elif "random" in eps and left != "random":
        i = showcase_episode(eps, "random", left)
        rule = (f"the episode where {'the simulator' if left == 'simulator' else left} ends nearest the goal "
                "relative to random programs")
    else:
        i = int(np.argmin(eps[left]["distance"][:, -1]))
        rule = f"the episode where {left} ends nearest the goal"
    goal = planned["setup"]["goal"][i]
    n = len(shown) + 1
    fig, axes = plt.subplots(1, n, figsize=(4.2 * n, 4.9))
    for ax, label in zip(axes[:-1], shown):
        res = eps[label]
        op, fp = res["object_path"][i], res["finger_path"][i]
        ax.add_patch(plt.Circle(goal, goal_radius, color="tab:green", alpha=0.25, lw=0))
        ax.scatter(op[:, 0], op[:, 1], c=np.arange(len(op)), cmap="Blues", s=12, vmin=-len(op) / 3)
        ax.plot(fp[:, 0], fp[:, 1], ":", color="goldenrod", lw=1.5)
        ax.scatter(*op[0], s=120, facecolors="none", edgecolors="tab:blue", lw=1.5)
        reached = res["distance"][i].min() < goal_radius
        name = textwrap.fill(label, 34)
        ax.set_title(f"{name}\n{'✓ reached the goal' if reached else '× goal not reached'}; final distance "
                     f"{res['distance'][i, -1]:.2f}", fontsize=9)
        ax.set_xlim(0, 1)
        ax.set_ylim(0, 1)
        ax.set_aspect("equal")
        ax.set_xticks([0, 0.5, 1])
        ax.set_yticks([0, 0.5, 1])
        ax.tick_params(labelsize=7)
        ax.set_xlabel("arena x", fontsize=8)
        ax.set_ylabel("arena y", fontsize=8)
    dist = axes[-1]
    styles = ("--", "-") if len(shown) == 2 else ("-",)
    for label, style in zip(shown, styles):
        dist.plot(eps[label]["distance"][i], style, label=label)
    if "random" in eps and "random" not in shown:
        dist.plot(eps["random"]["distance"][i], ":", color="grey", label="random programs (same start, goal)")
    dist.axhline(goal_radius, color="tab:green", lw=1, alpha=0.6, label="goal radius")
    dist.set_xlabel("control step")
    dist.set_ylabel("object-goal distance (arena units)")
    dist.set_title("Object-goal distance over the episode", fontsize=9)
    dist.legend(fontsize=7)
    # the episode panels' markers, named once for every panel
    keys = [plt.Circle((0, 0), 1, color="tab:green", alpha=0.25, lw=0, label="goal region"),
            Line2D([], [], marker="o", ls="", mfc="none", mec="tab:blue", mew=1.5, ms=9, label="object start"),
            Line2D([], [], marker="o", ls="", color="tab:blue", ms=4, label="object path (darker = later)"),
            Line2D([], [], ls=":", color="goldenrod", lw=1.5, label="finger path")]
    fig.legend(handles=keys, loc="lower center", ncol=4 if len(shown) == 2 else 2, fontsize=8, frameon=False,
               title="✓ / × in a panel's title: the object reached / never reached the goal region",
               title_fontsize=8)
    if len(shown) == 2:
        head = f"Held-out episode {i}: same planner, budget, start and goal, two frozen latents ({left} vs {right})"
    else:
        head = f"Held-out episode {i}: CEM planning with {controller_words(left)}"
    chars = int(11 * 4.2 * n)  # characters per line of a 10-pt title across the figure
    fig.suptitle(textwrap.fill(head, chars) + "\n" + textwrap.fill(f"({rule})", chars), fontsize=10)
    fig.tight_layout(rect=(0, 0.14 if len(shown) == 2 else 0.17, 1, 1))

    return save_figure(fig, out, "plan_episode")


def write_outputs(planned: dict, out: Path, goal_radius: float) -> list[Path]:
    """``distances.npz`` (object-goal distance over time per controller, atomically) and the episode figure."""
    save_npz(Path(out) / "distances.npz", {k: v["distance"] for k, v in planned["episodes"].items()}, compressed=True)
    return figure(planned, Path(out), goal_radius)


def table_lines(summary: dict) -> list[str]:
    """Markdown rows: controller, reach and median improvement, ours beside the paper's, then the rank test."""
    lines = ["| controller | goal-region reach (ours / paper) | median improvement, start − closest (ours / paper) | "
             "median improvement, start − final | mean improvement, start − final | object moved | "
             "rank ρ (model vs simulator) | top-k overlap (chance) | "
             "Δ=16 spread ratio | within-start R² | predicted displacement: misses / hits (true) | "
             "true end frames decoded: misses |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    # the paper's order (random, V, VX_t, VX_p, VFX), then any other controller as given: records are written
    # with sorted keys, so a summary read back from JSON is alphabetical
    order = [k for k in PAPER if k in summary] + [k for k in summary if k not in PAPER]
    for k, v in ((k, summary[k]) for k in order):
        p = PAPER.get(k)
        extra = " | ".join("—" if v.get(m) is None else (f"{v[m]:+.3f}" if m == "mean_improvement" else f"{v[m]:.0%}")
                           for m in ("mean_improvement", "object_moved"))
        # summaries written before the rank test have no rank keys; the random controller has them as None
        rank = ("— | —" if v.get("spearman") is None else
                f"{v['spearman']:+.2f} | {v['topk_overlap']:.2f} ({v['topk_chance']:.2f})")
        # the counterfactual fit (evaluate.counterfactual) came later than the rank test: older summaries lack it
        cf = " | ".join("—" if v.get(m) is None or not np.isfinite(v[m]) else f"{v[m]:+.2f}"
                        for m in ("spread_ratio", "within_r2"))
        disp = ("—" if v.get("miss_displacement") is None or not np.isfinite(v["miss_displacement"]) else
                f"{v['miss_displacement']:.3f} / {v['hit_displacement']:.3f} ({v['hit_true_displacement']:.3f})")
        control = v.get("decoded_truth_miss_displacement")
        disp += " | " + ("—" if control is None or not np.isfinite(control) else f"{control:.3f}")
        # the paper's improvement is the released planner's start − closest distance; records from before that
        # metric have only start − final, which is not shown beside it
        closest = v.get("median_closest_improvement")
        lines.append(f"| {k} | {v['reach']:.0%} / {f'{p[0]:.0%}' if p else '—'} | "
                     f"{'—' if closest is None else f'{closest:+.3f}'} / {f'{p[1]:.2f}' if p else '—'} | "
                     f"{v['median_improvement']:+.3f} | {extra} | {rank} | {cf} | {disp} |")
    # a table of nan and R² in the hundreds below zero reads as a bug; at the tiny preset it is the expected output
    # of an untrained-sized model on a handful of starts, so say so under the table (trained cpu-preset models read
    # a within-start R² down to about -5, docs/design.md "Planning: open-loop behaviour data and the rank test")
    degenerate_within_r2 = -100.0
    read = [v for v in summary.values() if v.get("spearman") is not None]
    nan = any(not np.isfinite(v[m]) for v in read for m in ("topk_overlap", "spread_ratio", "within_r2")
              if isinstance(v.get(m), float))
    worst = min((v["within_r2"] for v in read if np.isfinite(v.get("within_r2", float("nan")))), default=0.0)
    if nan or worst < degenerate_within_r2:
        lines += ["", f"Note: nan (a test with no start to read it on) and within-start R² as low as {worst:.0f} are "
                      "what a model of the tiny preset gives on a handful of starts and candidates: a smoke test, not "
                      "a result. Plan with runs of --preset cpu (or paper) for numbers worth reading."]
    return lines


def controller_labels(runs) -> dict[str, list[str]]:
    """Each run under its variant (so the paper's row stands beside it) when no two runs share one; otherwise
    each under its folder name."""
    variants = [(finished_run_config(r) or {}).get("variant") for r in runs]
    if None in variants or len(set(variants)) < len(variants):
        return {Path(r).name: [r] for r in runs}
    return {v: [r] for v, r in zip(variants, runs)}


def observations_fed(cfg: PlanConfig) -> int:
    """The most observations a decision feeds a model at once: the context, or fewer while the history (the start,
    ``settle`` steps and the steps controlled before the last replan) is shorter."""
    last_decision = (cfg.steps - 1) // cfg.replan * cfg.replan
    return min(cfg.context, cfg.settle + 1 + last_decision)


def check_models(cfg: PlanConfig, runs, data: str = "") -> None:
    """Every run's model read and held against what planning feeds it (:func:`pokeworld.model_inputs.checked_model`:
    finite weights, the store's streams, :func:`observations_fed` within its max_len, the Δ=4 and Δ=16 heads the
    cost reads), before the random controller or any decoder runs (callers of :func:`plan_runs` with runs from
    elsewhere call it first). ``data``: the decoders' store for every run (default: ``cfg.data``, else each run's
    own)."""
    option = f"--context {cfg.context} with --settle {cfg.settle}"
    for r in runs:
        checked_model(r, data or cfg.data or trained_store(r, "plan"), observations_fed(cfg), option,
                      horizons=tuple(d for d, _ in COST_TERMS))


PLAN_OUTPUTS = ("plan.json", "plan.md", "distances.npz", "plan_episode.png", "plan_episode.pdf")
"""The files ``pokeworld plan`` writes in its output folder."""


def run(cfg: PlanConfig) -> Path:
    if not cfg.runs and not cfg.simulator_controller:
        raise ConfigError("give at least one trained run directory with --runs (or plan with --simulator-controller)")
    # every run is checked before any is planned with: a bad last one must not fail after the others' work
    require_finished_runs(cfg.runs, "plan", "every --runs value must be a run folder: OUT is a positional argument "
                          "placed before --runs (pokeworld plan OUT --runs RUN1 RUN2), or use --out OUT", cfg.data)
    out = check_outputs(cfg.out, *PLAN_OUTPUTS)  # a user's plan.md in --out is refused before any planning
    check_models(cfg, cfg.runs)
    planned = plan_runs(cfg, controller_labels(cfg.runs))
    summary = planned["summary"]
    write_json(out / "plan.json", {"config": to_dict(cfg), "results": summary,
                                   "paper": {k: list(v) for k, v in PAPER.items()}})
    write_outputs(planned, out, cfg.goal_radius)
    lines = table_lines(summary)
    save_text(out / "plan.md", "\n".join(lines) + "\n")
    print("\n".join(lines))
    return out
