"""Numbers reported in the paper that several modules show beside ours (certificates, prediction errors, the glide
test, corpus statistics, planning) and the real-robot tables'. Never used as results of ours.

Each map experiment keeps its own paper values in its module (:mod:`pokeworld.experiments`).
Keys: experiment -> row -> column -> value (contact windows, ridge unless noted). Source: paper.tex.
"""

CERTIFICATES = {  # App. A "instrument hierarchy", App. C "pixel-derived certificates"
    "gru": {"log_m": 0.86, "gamma": 0.70, "log_k": 0.87},
    "drag": {"gamma": 0.89},
    "linear": {"log_m": 0.0, "gamma": 0.0, "log_k": 0.0},
    "mlp": {"log_m": 0.45, "gamma": 0.0},
    "gru_pixel": {"log_m": 0.72, "gamma": 0.43, "log_k": 0.78},
    "drag_pixel": {"gamma": 0.05},
    "gru_geom": {},  # ours: the GRU with explicit contact geometry; not in the paper
    "gru_notouch": {},  # not reported by the paper
    "gru_pixel_notouch": {},  # ours only
}

PREDICTION = {"direct16": 0.10, "rollout16": 0.19, "static16": 0.21}  # §4.2, arena units

GLIDE_TEST = {"true_gamma": 0.0002, "median_gamma": 0.049, "static": 0.144}
"""The glide test's references in true positions (App. C, γ ledger)."""
GLIDE_TEST_DECODED = {"median_gamma": 0.054}
"""The functional glide test's median-γ reference, decoded as the model's predictions are (Table "dose1")."""

CORPUS_STATS = {  # observables of the paper's default corpus (the calibration targets; pokeworld.sim.stats)
    "static16": ((0.205, 0.21), "λ-table caption; §4.2 (static 0.21)"),
    "static8": (0.109, "App. C, open-loop 8-step static baseline"),
    "glide_static16": (0.144, "App. C, γ ledger: static predictor on pure-glide windows"),
    "glide_median_gamma16": ((0.049, 0.054), "App. C, ledger / Dose–response 1: median-γ reference"),
    "glide_loss_share": (0.32, "App. C, Dose–response 1: glide loss share at weight 1"),
}

# ----------------------------------------------------------------------------- real robot (§5, App. C)
# Pairs are (IID, OOD) = (probe episodes, held-out tasks); errors in cm; readouts R^2 (ridge).
REAL_KUKA = {  # Table "kuka" (cfg7, far camera); "pred16" is the table's "16-step (cm)" column, which §5
    # calls the rollout error ("cut rollout error up to 29%": 8.2 -> 5.8)
    "V": {"force": (-0.05, -0.49), "position": (0.76, 0.48), "pred16": 8.2, "auc": (0.70, 0.54)},
    "VX": {"force": (-0.02, -0.70), "position": (0.75, 0.50), "pred16": 5.8, "auc": (0.77, 0.69)},
    "VX_t": {"force": (-0.04, -0.61), "position": (0.77, 0.46), "pred16": 6.2, "auc": (0.80, 0.72)},
    "VFX": {"force": (0.87, 0.56), "position": (0.98, 0.98), "pred16": 1.5, "auc": (0.86, 0.70)},
}
REAL_KUKA_STATIC16 = 3.8  # App. C "static baseline 3.8 cm"

REAL_VIEWPOINT = {  # Table "viewpoint": camera-only force (VX), best camera-only position, 16-step (cm)
    "far": {"force": -0.02, "position": (0.76, 0.48), "pred16": 5.8},
    "close": {"force": 0.10, "position": (0.48, 0.17), "pred16": None},
    "two_view": {"force": 0.08, "position": (0.81, 0.60), "pred16": 5.0},
}
REAL_VIEWPOINT_VFX = {"position": 0.98, "force_range": (0.84, 0.90)}  # App. C text: VFX across viewpoints

REAL_CFG1 = {  # Table "cfg1": arm -> scenes -> metrics ("pred16" = direct 16-step, Fig. "scissors" right)
    "V": {800: {"force": (-0.07, -0.32), "position": (0.18, -0.06), "pred16": 11.7, "auc_ood": 0.75},
          2000: {"force": (-0.05, -0.35), "position": (0.14, 0.04), "pred16": 12.5, "auc_ood": 0.70},
          4258: {"force": (-0.06, -0.30), "position": (0.23, 0.02), "pred16": 12.0, "auc_ood": 0.62}},
    "VX": {800: {"force": (-0.03, -0.31), "position": (0.33, 0.30), "pred16": 10.0, "auc_ood": 0.76},
           2000: {"force": (-0.03, -0.26), "position": (0.30, 0.22), "pred16": 10.2, "auc_ood": 0.73},
           4258: {"force": (-0.04, -0.27), "position": (0.34, 0.24), "pred16": 10.4, "auc_ood": 0.77}},
    "VF": {800: {"force": (0.15, -0.16), "position": (0.95, 0.95), "pred16": 2.9, "auc_ood": 0.78},
           2000: {"force": (0.15, -0.19), "position": (0.95, 0.96), "pred16": 2.8, "auc_ood": 0.74},
           4258: {"force": (0.15, -0.06), "position": (0.96, 0.96), "pred16": 2.7, "auc_ood": 0.85}},
    "VFX": {800: {"force": (0.90, 0.86), "position": (0.96, 0.96), "pred16": 2.2, "auc_ood": 0.88},
            2000: {"force": (0.91, 0.85), "position": (0.96, 0.97), "pred16": 2.5, "auc_ood": 0.88},
            4258: {"force": (0.92, 0.89), "position": (0.97, 0.97), "pred16": 2.3, "auc_ood": 0.89}},
}
REAL_CFG1_SCENES = 4258
REAL_CFG1_STATIC16 = 3.3
REAL_CFG1_NOTES = {"V_position_compute_control": 0.16, "V_rollout16_full": 15.7}  # App. C text

REAL_CROSS = {  # Table "cross-embodiment": V and VFX, cfg7 vs cfg1 (full scale)
    "V": {"cfg7": {"position": (0.76, 0.48), "auc_ood": 0.54, "pred16": 8.2, "static16": 3.8},
          "cfg1": {"position": (0.23, 0.02), "auc_ood": 0.62, "pred16": 15.7, "static16": 3.3}},
    "VFX": {"cfg7": {"position": (0.98, 0.98), "force_ood": 0.56, "auc_ood": 0.70, "pred16": 1.5, "static16": 3.8},
            "cfg1": {"position": (0.97, 0.97), "force_ood": 0.89, "auc_ood": 0.89, "pred16": 2.2, "static16": 3.3}},
}

REAL_UNTRAINED = {  # Table "rand": 16-step errors in metres
    "VFX": {"force": (0.94, 0.91), "position": (0.97, 0.98), "pred16_m": 23.0, "auc": (0.87, 0.88)},
    "V": {"force": (-0.01, -0.16), "position": (0.21, 0.13), "pred16_m": 185.0, "auc": (0.72, 0.51)},
}
REAL_FORCE_RETENTION = {"VF": 0.15, "untrained_VFX": 0.91}  # §5: VF far below the untrained bound (OOD)

REAL_FORECAST = {  # Table "futforce": Δ (steps) -> (IID, OOD)
    "VFX": {1: (0.72, 0.68), 4: (0.47, 0.51)},
    "VX": {1: (0.18, -0.07), 4: (0.15, -0.05)},
    "persistence": {1: (0.65, 0.61), 4: (0.24, 0.31)},
}
REAL_FORECAST_SCALING = {  # App. C text: held-out Δ=4 forecast R^2 per scale, and model − persistence 95 % CIs
    "VFX": {800: 0.39, 2000: 0.50, 4258: 0.51},
    "VX": {800: -0.05, 2000: -0.11, 4258: -0.05},
}
REAL_FORECAST_CI = {"VFX": {800: (0.01, 0.17), 4258: (0.14, 0.28)}, "VX": {"every scale": (-0.55, -0.15)}}

REAL_JOINT = {  # §5 "One model, two robots": configuration-blind VFX vs the specialists
    "kuka_force_ood": {"specialist": 0.56, "joint": 0.89},
}

PLANNING = {  # App. C Table "planning": controller -> (goal-region reach, median distance improvement)
    "random": (0.01, 0.00), "V": (0.20, 0.02), "VX_t": (0.38, 0.15), "VX_p": (0.44, 0.18), "VFX": (0.57, 0.24),
}

# ----------------------------------------------------------------------------- values the reproduction ledger adds
# (pokeworld.reproduction; the other experiments' values stay in their modules, e.g. experiments.factorial.FACTORIAL)

TARGETS_PER_SEED = {  # Table "targets": ridge R² on contact windows, seeds (s0, s1); FACTORIAL holds their means
    "V": {"log_k": (-0.02, -0.02), "log_m": (0.15, 0.14)},
    "VF": {"log_k": (-0.02, -0.01), "log_m": (0.19, 0.21)},
    "VX_p": {"log_k": (-0.02, -0.01), "log_m": (0.18, 0.18)},
    "VX_t": {"log_k": (0.40, 0.43), "log_m": (0.26, 0.25)},
    "VX": {"log_k": (0.46, 0.45), "log_m": (0.26, 0.28)},
    "VFX": {"log_k": (0.50, 0.49), "log_m": (0.29, 0.31)},
}

COMPOSITION = (0.96, 1.00)  # App. C "Composition probes": finger, object, relative position, every variant
OPEN_LOOP = {  # App. C after Table "targets": multi-horizon position probes and open-loop 8-step decoded error
    "object_pos": (0.95, 0.98), "rollout8": (0.062, 0.082)}  # (its static-8 baseline: CORPUS_STATS["static8"])

GAMMA_PLATEAU = 0.13  # abstract, §4.5: γ "plateaus near 0.13" in every model, both probe families
GAMMA_LEDGER = {  # App. C, the γ intervention ledger (Fig. "ledger"): best γ readout at each stage
    "single_horizon": 0.00, "multi_horizon": 0.05, "motion_channel": 0.12}  # later mechanisms: "no gain"

PIXEL_READOUT_RATIO = {  # §4.5 / App. C "Pixel-derived certificates": model readout / pixel certificate
    "log_k": (0.64, 0.79), "log_m": 0.43, "gamma": 0.30}
FRAME_AVERAGED_LOG_K_CERTIFICATE = 0.0  # §4.4: with frame-averaged touch "stiffness is unrecoverable"
MODEL_PARAMETERS = 5_000_000  # §3 "Models are ~5M parameters" (and Limitations)
DRIFT_CERTIFICATE = 0.03  # App. C "Constructing the cells" (i): per-episode drift acceleration, rejected

GAIN_CELL = {  # App. C "Constructing the cells": the actuation gain g as its own corpus, and that run's probes
    "linear": -0.013, "recurrent": 0.689, "ridge": -0.011, "mlp": -0.010,
    "log_k": 0.34, "log_m": 0.20, "object_pos": 0.96}

CONTROLS_MLP = {  # Table "controls": the early-stopped MLP readouts in parentheses (ridge: experiments.controls)
    "VFX": {"log_m": 0.26, "gamma": 0.06, "log_k": 0.50},
    "VFX+sysid": {"log_m": 0.70, "gamma": 0.39, "log_k": 0.91},
    "VFX-gnll": {"log_m": 0.29, "gamma": 0.07, "log_k": 0.48},
    "V-recon": {"log_m": 0.00, "gamma": 0.00, "log_k": -0.10},
    "VFX-recon": {"log_m": 0.19, "gamma": -0.04, "log_k": 0.63},
}
CONTROLS_DIRECT16 = {"VFX": 0.098, "VFX+sysid": 0.101, "VFX-gnll": 0.143}  # Table "controls" (recon rows: "—")

REAL_CORPUS = {  # §5 and App. C: the RH20T corpora (cfg7 KUKA, cfg1 Flexiv)
    "kuka_episodes": 896, "kuka_tasks": 56, "flexiv_episodes": 4258,
    "onset_base_rate": {"cfg7": 0.0275, "cfg1": 0.0064}}  # contact-onset base rates (App. C protocol notes)
