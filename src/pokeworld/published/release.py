"""Numbers from the code the paper's authors released (github.com/tantansir/latent-world-model-identifiability, MIT),
shown beside ours and beside the paper's table values. Never used as results of ours. Facts and numbers carry over;
the code does not (ours is written here).

The paper's tables give the mean of two seeds; these are single runs, so a run of ours is compared with the released
run of the same variant and seed. Each run is the JSON its ``train.py`` wrote (``source``: the file inside
:data:`SOURCE_REPO`, at :data:`RESULTS_COMMIT`). Keys follow our records: ridge (``ridge``) and MLP (``mlp``) R² on
contact windows (≥ 2 contact frames in the 16-frame context) of the probe-test split (3,228 windows in
exp/e003_motion): the released files' ``probe.trunk.contact`` / ``probe.trunk_mlp.contact`` entries, log_stiffness
-> log_k, log_mass -> log_m, rounded to four decimals; errors in arena units: ``direct16`` = ``direct16_pos_err``,
``rollout16`` = ``rollout_pos_err["16"]``, ``static16`` = ``static_baseline_err["16"]``; ``object_pos_frame`` =
``probe_r2_pos_frame`` (the frame-position readout); ``params`` = ``sum(p.numel() for p in model.parameters())``;
``minutes`` the run's own wall time.
"""

SOURCE_REPO = "tantansir/latent-world-model-identifiability"
RESULTS_COMMIT = "a19f5b8716ad725694cc28e52441ca81f1e3fdc9"
"""The commit of the per-run results below (the later ``*_ac`` rerun is at :data:`MODEL_COMMIT`)."""
MODEL_COMMIT = "9537ee017fe73676e5803286544600c66f5cad2c"
"""The commit of ``exp/e003_motion/model.py`` and ``train.py`` read for the objective and model."""

#: The multi-horizon runs behind the paper's Table "targets" (exp/e003_motion, λ 0.02, 20,000 steps, batch 128).
#: (variant, seed) -> values: every variant at seed 0 (the paper's operating point); VFX and VF at both seeds, with
#: their frame-position readout too.
MULTI_HORIZON = {
    ("V", 0): {"source": "exp/e003_motion/results/V_s0_l0.02.json", "params": 4_090_208, "minutes": 34.0,
               "ridge": {"log_k": -0.0191, "log_m": 0.1467, "gamma": 0.0933},
               "mlp": {"log_k": -0.0050, "log_m": -0.0002, "gamma": -0.0028},
               "direct16": 0.1085, "rollout16": 0.1226, "static16": 0.2048},
    ("VF", 0): {"source": "exp/e003_motion/results/VF_s0_l0.02.json",
                "ridge": {"log_k": -0.0157, "log_m": 0.1936, "gamma": 0.1420},
                "mlp": {"log_k": -0.0962, "log_m": 0.1324, "gamma": 0.0523},
                "object_pos_frame": 0.977, "direct16": 0.0933, "rollout16": 0.1125, "static16": 0.2048,
                "params": 4_140_384, "minutes": 35.3},
    ("VX_p", 0): {"source": "exp/e003_motion/results/VXp_s0_l0.02.json", "params": 4_111_560, "minutes": 33.0,
                  "ridge": {"log_k": -0.0203, "log_m": 0.1784, "gamma": 0.0973},
                  "mlp": {"log_k": 0.0011, "log_m": -0.0053, "gamma": -0.0051},
                  "direct16": 0.0998, "rollout16": 0.1223, "static16": 0.2048},
    ("VX_t", 0): {"source": "exp/e003_motion/results/VXt_s0_l0.02.json", "params": 4_112_814, "minutes": 35.2,
                  "ridge": {"log_k": 0.4010, "log_m": 0.2611, "gamma": 0.1245},
                  "mlp": {"log_k": 0.3968, "log_m": 0.2004, "gamma": 0.0499},
                  "direct16": 0.1027, "rollout16": 0.1432, "static16": 0.2048},
    ("VX", 0): {"source": "exp/e003_motion/results/VX_s0_l0.02.json", "params": 4_134_166, "minutes": 36.0,
                "ridge": {"log_k": 0.4598, "log_m": 0.2558, "gamma": 0.1291},
                "mlp": {"log_k": 0.4386, "log_m": 0.1947, "gamma": 0.0532},
                "direct16": 0.1006, "rollout16": 0.1353, "static16": 0.2048},
    # MLP log k: the file's probe.trunk_mlp.contact.log_stiffness is 0.495849…, so 0.4958
    ("VFX", 0): {"source": "exp/e003_motion/results/VFX_s0_l0.02.json",
                 "ridge": {"log_k": 0.4999, "log_m": 0.2926, "gamma": 0.1245},
                 "mlp": {"log_k": 0.4958, "log_m": 0.2597, "gamma": 0.0590},
                 "object_pos_frame": 0.98, "direct16": 0.0985, "rollout16": 0.1334, "static16": 0.2048,
                 "object_vel_moving": 0.7859, "params": 4_184_342, "minutes": 34.2},
    ("VFX", 1): {"source": "exp/e003_motion/results/VFX_s1_l0.02.json",
                 "ridge": {"log_k": 0.4914, "log_m": 0.3087, "gamma": 0.1267},
                 "mlp": {"log_k": 0.4823, "log_m": 0.2773, "gamma": 0.0570},
                 "object_pos_frame": 0.9778, "direct16": 0.0988, "rollout16": 0.1366, "static16": 0.2048,
                 "object_vel_moving": 0.7838, "params": 4_184_342, "minutes": 34.7},
    ("VF", 1): {"source": "exp/e003_motion/results/VF_s1_l0.02.json",
                "ridge": {"log_k": -0.0126, "log_m": 0.2134, "gamma": 0.1437},
                "mlp": {"log_k": -0.0001, "log_m": -0.0025, "gamma": -0.0031},
                "object_pos_frame": 0.9746, "direct16": 0.0976, "rollout16": 0.1111, "static16": 0.2048,
                "params": 4_140_384, "minutes": 35.4},
}

#: The same experiment's runs at λ 0.1 (``train.py``'s default, so their files carry no ``_l`` suffix; the s1 files
#: record ``"lam": 0.1`` and the s0 files' logged totals add up with 0.1 × sigreg): the factorial the paper says keeps
#: Table "targets"' ordering at that weight. The release has V, VX_t, VX and VFX only (no VF or VX_p), seeds 0 and 1.
LAMBDA_0_1 = {
    ("V", 0): {"source": "exp/e003_motion/results/V_s0.json", "params": 4_090_208, "minutes": 41.3,
               "ridge": {"log_k": -0.0188, "log_m": 0.1012, "gamma": 0.0299},
               "mlp": {"log_k": 0.0012, "log_m": -0.0008, "gamma": -0.0093},
               "object_pos_frame": 0.6778, "direct16": 0.1840, "rollout16": 0.2106, "static16": 0.2048},
    ("V", 1): {"source": "exp/e003_motion/results/V_s1.json", "params": 4_090_208, "minutes": 41.3,
               "ridge": {"log_k": -0.0242, "log_m": 0.0894, "gamma": 0.0142},
               "mlp": {"log_k": -0.0068, "log_m": 0.0032, "gamma": -0.0009},
               "object_pos_frame": 0.9370, "direct16": 0.1222, "rollout16": 0.2254, "static16": 0.2048},
    ("VX_t", 0): {"source": "exp/e003_motion/results/VXt_s0.json", "params": 4_112_814, "minutes": 41.7,
                  "ridge": {"log_k": 0.1593, "log_m": 0.1371, "gamma": 0.0589},
                  "mlp": {"log_k": 0.1871, "log_m": 0.0998, "gamma": -0.0320},
                  "object_pos_frame": 0.8943, "direct16": 0.1324, "rollout16": 0.1943, "static16": 0.2048},
    ("VX_t", 1): {"source": "exp/e003_motion/results/VXt_s1.json", "params": 4_112_814, "minutes": 38.2,
                  "ridge": {"log_k": 0.1442, "log_m": 0.1332, "gamma": 0.0625},
                  "mlp": {"log_k": 0.1672, "log_m": 0.1010, "gamma": -0.0403},
                  "object_pos_frame": 0.8895, "direct16": 0.1362, "rollout16": 0.1989, "static16": 0.2048},
    ("VX", 0): {"source": "exp/e003_motion/results/VX_s0.json", "params": 4_134_166, "minutes": 42.1,
                "ridge": {"log_k": 0.2252, "log_m": 0.1379, "gamma": 0.0482},
                "mlp": {"log_k": 0.2352, "log_m": 0.0985, "gamma": -0.0268},
                "object_pos_frame": 0.9299, "direct16": 0.1272, "rollout16": 0.1877, "static16": 0.2048},
    ("VX", 1): {"source": "exp/e003_motion/results/VX_s1.json", "params": 4_134_166, "minutes": 42.1,
                "ridge": {"log_k": 0.2268, "log_m": 0.1226, "gamma": 0.0452},
                "mlp": {"log_k": 0.2345, "log_m": 0.1112, "gamma": -0.0343},
                "object_pos_frame": 0.9169, "direct16": 0.1304, "rollout16": 0.2080, "static16": 0.2048},
    ("VFX", 0): {"source": "exp/e003_motion/results/VFX_s0.json", "params": 4_184_342, "minutes": 42.3,
                 "ridge": {"log_k": 0.2445, "log_m": 0.1820, "gamma": 0.0531},
                 "mlp": {"log_k": 0.2738, "log_m": 0.1198, "gamma": -0.0317},
                 "object_pos_frame": 0.9596, "direct16": 0.1110, "rollout16": 0.1862, "static16": 0.2048,
                 "object_vel_moving": 0.6162},
    ("VFX", 1): {"source": "exp/e003_motion/results/VFX_s1.json", "params": 4_184_342, "minutes": 34.9,
                 "ridge": {"log_k": 0.3028, "log_m": 0.2001, "gamma": 0.0638},
                 "mlp": {"log_k": 0.3064, "log_m": 0.1472, "gamma": -0.0447},
                 "object_pos_frame": 0.9599, "direct16": 0.1110, "rollout16": 0.1900, "static16": 0.2048,
                 "object_vel_moving": 0.6260},
}

#: VFX across the SIGReg weight (the runs behind Table "lambda"): (λ, seed) -> the run. λ 0.3, 0.01 and 0.005 have
#: seed 0 only (``VFX_s0_l<λ>.json``); λ 0.1 and 0.02 are the VFX runs above. ``object_vel_moving`` is the file's
#: ``probe.velocity_r2.moving`` (the paper's velocity column: 0.79 at λ 0.02 is the two seeds' 0.786 / 0.784).
LAMBDA_SWEEP_VFX = {
    (0.3, 0): {"source": "exp/e003_motion/results/VFX_s0_l0.3.json", "params": 4_184_342, "minutes": 34.8,
               "ridge": {"log_k": 0.1204, "log_m": 0.1185, "gamma": 0.0062},
               "mlp": {"log_k": 0.0018, "log_m": -0.0058, "gamma": -0.0054},
               "object_pos_frame": 0.9087, "direct16": 0.1284, "rollout16": 0.2499, "object_vel_moving": 0.5356},
    (0.01, 0): {"source": "exp/e003_motion/results/VFX_s0_l0.01.json", "params": 4_184_342, "minutes": 50.6,
                "ridge": {"log_k": 0.5435, "log_m": 0.3182, "gamma": 0.1231},
                "mlp": {"log_k": 0.5571, "log_m": 0.2925, "gamma": 0.0591},
                "object_pos_frame": 0.9827, "direct16": 0.0956, "rollout16": 0.1268, "object_vel_moving": 0.7893},
    (0.005, 0): {"source": "exp/e003_motion/results/VFX_s0_l0.005.json", "params": 4_184_342, "minutes": 38.2,
                 "ridge": {"log_k": 0.5737, "log_m": 0.3229, "gamma": 0.1146},
                 "mlp": {"log_k": 0.5685, "log_m": 0.3114, "gamma": 0.0641},
                 "object_pos_frame": 0.9836, "direct16": 0.0951, "rollout16": 0.1311, "object_vel_moving": 0.7993},
    **{(0.1, s): LAMBDA_0_1[("VFX", s)] for s in (0, 1)},
    **{(0.02, s): MULTI_HORIZON[("VFX", s)] for s in (0, 1)},
}

#: VFX with the frozen flow sensor (exp/e003_motion, λ 0.02, seed 0; ``train.py --flow``: the sensor's two dense flow
#: fields appended to the frame and its difference as image channels, ``--data2`` (tag ``_g``) the glide-enriched
#: training split ``train2``, ``--logspeed`` (tag ``_ls``) a per-pixel log |flow| channel): ``fl`` is the γ ledger's
#: "frozen flow velocity sensor" (velocity 0.88 moving windows, γ plateau unchanged), ``fl_g`` → ``fl_g_ls`` the
#: coordinate test's "0.08 → 0.33" (ridge γ on glide windows). ``gamma_glide`` = ``probe.trunk.glide.gamma``.
FLOW_SENSOR_VFX = {
    "fl": {"source": "exp/e003_motion/results/VFX_s0_l0.02_fl.json", "params": 4_184_918, "minutes": 46.2,
           "ridge": {"log_k": 0.4528, "log_m": 0.2753, "gamma": 0.1096}, "gamma_glide": 0.0124,
           "mlp": {"log_k": 0.4654, "log_m": 0.2317, "gamma": 0.0544}, "mlp_gamma_glide": -0.0130,
           "object_vel_moving": 0.8796, "object_pos_frame": 0.9743, "direct16": 0.0958, "rollout16": 0.1241},
    "fl_g": {"source": "exp/e003_motion/results/VFX_s0_l0.02_fl_g.json", "params": 4_184_918, "minutes": 46.1,
             "ridge": {"log_k": 0.4175, "log_m": 0.2646, "gamma": 0.1008}, "gamma_glide": 0.0820,
             "mlp": {"log_k": 0.4323, "log_m": 0.2213, "gamma": 0.0697}, "mlp_gamma_glide": -0.0121,
             "object_vel_moving": 0.8530, "object_pos_frame": 0.9667, "direct16": 0.1032, "rollout16": 0.1358},
    "fl_g_ls": {"source": "exp/e003_motion/results/VFX_s0_l0.02_fl_g_ls.json", "params": 4_185_206, "minutes": 51.8,
                "ridge": {"log_k": 0.4477, "log_m": 0.2520, "gamma": 0.1105}, "gamma_glide": 0.3332,
                "mlp": {"log_k": 0.4590, "log_m": 0.2241, "gamma": 0.0610}, "mlp_gamma_glide": -0.0102,
                "object_vel_moving": 0.8223, "object_pos_frame": 0.9655, "direct16": 0.1061, "rollout16": 0.1465},
    "fl_g_gw4": {"source": "exp/e003_motion/results/VFX_s0_l0.02_fl_g_gw4.json", "params": 4_184_918, "minutes": 60.2,
                 "ridge": {"log_k": 0.3409, "log_m": 0.2336, "gamma": 0.1207}, "gamma_glide": 0.1476,
                 "mlp": {"log_k": 0.4066, "log_m": 0.2205, "gamma": 0.0910}, "mlp_gamma_glide": -0.0124,
                 "object_vel_moving": 0.7938, "object_pos_frame": 0.9615, "direct16": 0.1090, "rollout16": 0.1461},
    "fl_g_gw16": {"source": "exp/e003_motion/results/VFX_s0_l0.02_fl_g_gw16.json", "params": 4_184_918,
                  "minutes": 56.5, "ridge": {"log_k": 0.2024, "log_m": 0.1768, "gamma": 0.0989}, "gamma_glide": 0.2073,
                  "mlp": {"log_k": 0.2720, "log_m": 0.1964, "gamma": 0.0740}, "mlp_gamma_glide": 0.0052,
                  "object_vel_moving": 0.6996, "object_pos_frame": 0.9331, "direct16": 0.1281, "rollout16": 0.1783},
    "fl_g_gw64": {"source": "exp/e003_motion/results/VFX_s0_l0.02_fl_g_gw64.json", "params": 4_184_918,
                  "minutes": 53.5, "ridge": {"log_k": 0.0992, "log_m": 0.1470, "gamma": 0.0910}, "gamma_glide": 0.2728,
                  "mlp": {"log_k": 0.0958, "log_m": 0.1678, "gamma": 0.0668}, "mlp_gamma_glide": -0.0093,
                  "object_vel_moving": 0.6476, "object_pos_frame": 0.8994, "direct16": 0.1448, "rollout16": 0.1843},
}
#: Dose–response 1 (Table "dose1") is the flow-input VFX on the glide-enriched split with zero-contact episodes drawn
#: W times as often (``--glidew W``, tags ``_gw4/16/64``; W = 1 is ``fl_g``): its log k 0.42 / 0.34 / 0.20 / 0.10,
#: velocity 0.85 / 0.79 / 0.70 / 0.65 and glide-window γ 0.08 → 0.27 are these runs' to two decimals.
DOSE_GLIDE_RUNS = {1.0: "fl_g", 4.0: "fl_g_gw4", 16.0: "fl_g_gw16", 64.0: "fl_g_gw64"}

#: The objective-attribution controls (Table "controls"; exp/e003_motion, λ 0.02, seed 0): ``--sysid`` (``_sid``),
#: ``--nll`` (``_nll``), ``--recon`` (``_rc``, V and VFX; pixel targets, so no latent rollout: direct-16 None). The
#: table's velocity column is ``object_vel_moving`` (``probe.velocity_r2.moving``), its position ``object_pos_frame``.
CONTROL_RUNS = {
    "VFX+sysid": {"source": "exp/e003_motion/results/VFX_s0_l0.02_sid.json", "params": 4_203_161, "minutes": 43.3,
        "ridge": {"log_k": 0.9106, "log_m": 0.7193, "gamma": 0.4499}, "gamma_glide": 0.4229,
        "mlp": {"log_k": 0.9094, "log_m": 0.6973, "gamma": 0.3937}, "mlp_gamma_glide": 0.0068,
        "object_vel": 0.74, "object_vel_moving": 0.7771, "object_pos_frame": 0.975,
        "direct16": 0.1011, "rollout16": 0.1362},
    "VFX-gnll": {"source": "exp/e003_motion/results/VFX_s0_l0.02_nll.json", "params": 4_262_700, "minutes": 36.6,
        "ridge": {"log_k": 0.4932, "log_m": 0.3055, "gamma": 0.0965}, "gamma_glide": 0.0364,
        "mlp": {"log_k": 0.4837, "log_m": 0.2854, "gamma": 0.0741}, "mlp_gamma_glide": -0.0155,
        "object_vel": 0.8708, "object_vel_moving": 0.8828, "object_pos_frame": 0.9958,
        "direct16": 0.1431, "rollout16": 0.1205},
    "V-recon": {"source": "exp/e003_motion/results/V_s0_l0.02_rc.json", "params": 8_204_609, "minutes": 61.8,
        "ridge": {"log_k": -0.0124, "log_m": 0.1547, "gamma": 0.0817}, "gamma_glide": -0.1127,
        "mlp": {"log_k": -0.0003, "log_m": 0.0024, "gamma": -0.0009}, "mlp_gamma_glide": 0.0012,
        "object_vel": 0.3741, "object_vel_moving": 0.4673, "object_pos_frame": 0.7448,
        "direct16": None, "rollout16": None},
    "VFX-recon": {"source": "exp/e003_motion/results/VFX_s0_l0.02_rc.json", "params": 8_298_743, "minutes": 62.5,
        "ridge": {"log_k": 0.6132, "log_m": 0.1855, "gamma": 0.0327}, "gamma_glide": -0.1216,
        "mlp": {"log_k": 0.6299, "log_m": 0.1891, "gamma": -0.037}, "mlp_gamma_glide": -0.0107,
        "object_vel": 0.5592, "object_vel_moving": 0.6419, "object_pos_frame": 0.9463,
        "direct16": None, "rollout16": None},
}

#: Dose–response 2 (Table "dose2": the contact-frame touch weight ``--touchw``, tags ``_tw1 / _tw0.25 / _tw0``; the
#: default 4 is the VFX of :data:`MULTI_HORIZON`), on the standard split without flow input.
DOSE_TOUCH_RUNS = {
    1.0: {"source": "exp/e003_motion/results/VFX_s0_l0.02_tw1.json", "params": 4_184_342, "minutes": 37.5,
        "ridge": {"log_k": 0.374, "log_m": 0.2843, "gamma": 0.1354}, "gamma_glide": 0.2547,
        "mlp": {"log_k": 0.3892, "log_m": 0.2202, "gamma": 0.0415}, "mlp_gamma_glide": -0.0063,
        "object_vel": 0.7749, "object_vel_moving": 0.797, "object_pos_frame": 0.9786,
        "direct16": 0.0927, "rollout16": 0.1146},
    0.25: {"source": "exp/e003_motion/results/VFX_s0_l0.02_tw0.25.json", "params": 4_184_342, "minutes": 36.8,
        "ridge": {"log_k": 0.1243, "log_m": 0.2566, "gamma": 0.1335}, "gamma_glide": 0.2962,
        "mlp": {"log_k": 0.0991, "log_m": 0.1987, "gamma": 0.0493}, "mlp_gamma_glide": -0.0048,
        "object_vel": 0.803, "object_vel_moving": 0.8222, "object_pos_frame": 0.9791,
        "direct16": 0.0918, "rollout16": 0.1084},
    0.0: {"source": "exp/e003_motion/results/VFX_s0_l0.02_tw0.json", "params": 4_184_342, "minutes": 35.8,
        "ridge": {"log_k": -0.0055, "log_m": 0.2124, "gamma": 0.142}, "gamma_glide": 0.3204,
        "mlp": {"log_k": -0.0937, "log_m": 0.146, "gamma": 0.0496}, "mlp_gamma_glide": 0.002,
        "object_vel": 0.8046, "object_vel_moving": 0.8217, "object_pos_frame": 0.9783,
        "direct16": 0.0926, "rollout16": 0.1063},
}

#: VFX on the contact-poor training split (``--dsuf 4``, tag ``_d4``; probed on the standard probe split, whose
#: 3,228 contact test windows it shares): §4.4 "Data coverage"'s log k 0.05, log m 0.11, position 0.87, velocity 0.58.
CONTACT_POOR_VFX = {"source": "exp/e003_motion/results/VFX_s0_l0.02_d4.json", "params": 4_184_342, "minutes": 36.5,
        "ridge": {"log_k": 0.046, "log_m": 0.1108, "gamma": 0.0682}, "gamma_glide": 0.0965,
        "mlp": {"log_k": -0.0012, "log_m": 0.0064, "gamma": -0.003}, "mlp_gamma_glide": -0.0043,
        "object_vel": 0.4871, "object_vel_moving": 0.5778, "object_pos_frame": 0.8663,
        "direct16": 0.1812, "rollout16": 0.2995}

DRIFT_LINEAR_CERTIFICATE = {"drift_x": 0.038, "drift_y": 0.019}
"""The release's linear certificate of a drift acceleration of the object on raw 16-step windows, all windows
(exp/e003_motion/results/drift_probe.json, ``cert_linear_raw``; its review_fixes.py, mode "drift"): its generator
(exp/e001_xmodal_jepa/pokeworld.py) fixes drag at 1.5 whenever drift is on, so the number is construction (ii)'s of
App. C "Constructing the cells", though the paper quotes 0.03 for (i)."""

#: variant (our name) -> its released run at the paper's operating point (λ 0.02, seed 0): the seed-0 runs of
#: :data:`MULTI_HORIZON`, the same dicts.
RUNS: dict[str, dict] = {v: MULTI_HORIZON[(v, 0)] for v in ("V", "VF", "VX_p", "VX_t", "VX", "VFX")}

#: The authors' own rerun of VFX with corrected action windows (``--acorr``: the head at t reads the actions that
#: produce states t+1..t+Δ, as pokeworld's always do). Its parameter count includes the predictor's 37,824-parameter
#: oracle-conditioning embedding (``p_emb``), added to model.py after the runs above and unused without ``--oracle``.
CORRECTED_ACTIONS_VFX = {
    "source": "exp/e003_motion/results/VFX_s0_l0.02_ac.json", "commit": MODEL_COMMIT, "params": 4_222_166,
    "ridge": {"log_k": 0.4863, "log_m": 0.2986, "gamma": 0.1150},
    "mlp": {"log_k": 0.4884, "log_m": 0.2760, "gamma": 0.0396},
    "direct16": 0.0964, "rollout16": 0.1333, "static16": 0.2048}
ORACLE_EMBEDDING_PARAMS = 37_824
"""``Predictor.p_emb`` (Linear(3, 192) + Linear(192, 192)): in model.py at :data:`MODEL_COMMIT`, not in the runs."""

#: The single-horizon first experiment (exp/e001_xmodal_jepa: Δ = 1 only, no multi-horizon heads; not the
#: configuration of Table "targets"'s probe columns, shown to say how much the multi-horizon objective adds; its
#: ``probe_r2_pos_frame`` is the single-horizon position column of that table, §4.2's lazy equilibrium). Ridge,
#: contact windows.
SINGLE_HORIZON = {
    ("V", 0): {"source": "exp/e001_xmodal_jepa/results/V_s0.json",
               "ridge": {"log_k": -0.0107, "log_m": 0.0206, "gamma": -0.0214}, "object_pos_frame": 0.0381,
               "params": 4001856, "minutes": 32.1},
    ("VX_p", 0): {"source": "exp/e001_xmodal_jepa/results/VXp_s0.json",
                  "ridge": {"log_k": -0.0102, "log_m": 0.0457, "gamma": -0.0134}, "object_pos_frame": 0.094,
                  "params": 4020772, "minutes": 39.9},
    ("VX_t", 0): {"source": "exp/e001_xmodal_jepa/results/VXt_s0.json",
                  "ridge": {"log_k": 0.3008, "log_m": 0.0399, "gamma": 0.0018}, "object_pos_frame": 0.1717,
                  "params": 4021063, "minutes": 40.0},
    ("VX", 0): {"source": "exp/e001_xmodal_jepa/results/VX_s0.json",
                "ridge": {"log_k": 0.3343, "log_m": 0.0497, "gamma": 0.0089}, "object_pos_frame": 0.5795,
                "params": 4039979, "minutes": 32.0},
    ("VFX", 0): {"source": "exp/e001_xmodal_jepa/results/VFX_s0.json",
                 "ridge": {"log_k": 0.2662, "log_m": 0.0821, "gamma": 0.0009}, "object_pos_frame": 0.8817,
                 "params": 4090155, "minutes": 37.7},
    ("VF", 0): {"source": "exp/e001_xmodal_jepa/results/VF_s0.json",
                "ridge": {"log_k": 0.0636, "log_m": 0.0699, "gamma": 0.0057}, "object_pos_frame": 0.6986,
                "params": 4052032, "minutes": 33.4},
}


#: The multiscale experiment (exp/e002_multiscale: multi-horizon heads, the experiment before the e003 runs above),
#: whose V position (0.890) and VFX position (0.980) are §4.2's "multi-horizon heads restore it to 0.89 ... compose to
#: 0.98". ``direct16`` = ``direct16_pos_err``, ``rollout16`` = ``rollout_pos_err["16"]``; ridge on contact windows.
MULTISCALE = {
    ("V", 0): {"source": "exp/e002_multiscale/results/V_s0.json",
               "ridge": {"log_k": -0.0169, "log_m": 0.0024, "gamma": -0.0055}, "object_pos_frame": 0.8903,
               "direct16": 0.1446, "rollout16": 0.3615, "static16": 0.2048, "params": 4089920},
    ("VFX", 0): {"source": "exp/e002_multiscale/results/VFX_s0.json",
                 "ridge": {"log_k": 0.3061, "log_m": 0.1455, "gamma": 0.0121}, "object_pos_frame": 0.9803,
                 "direct16": 0.1142, "rollout16": 0.2338, "static16": 0.2048, "params": 4184054},
}


def released(variant: str, seed: int, table: dict = MULTI_HORIZON) -> dict:
    """The released run of ``variant`` at ``seed`` (empty when none was released or its numbers are not
    transcribed here)."""
    return table.get((variant, seed), {})


__all__ = ["SOURCE_REPO", "RESULTS_COMMIT", "MODEL_COMMIT", "MULTI_HORIZON", "LAMBDA_0_1", "LAMBDA_SWEEP_VFX",
           "FLOW_SENSOR_VFX", "DOSE_GLIDE_RUNS", "CONTROL_RUNS", "DOSE_TOUCH_RUNS", "CONTACT_POOR_VFX", "RUNS",
           "CORRECTED_ACTIONS_VFX", "ORACLE_EMBEDDING_PARAMS", "DRIFT_LINEAR_CERTIFICATE", "SINGLE_HORIZON",
           "MULTISCALE", "released"]
