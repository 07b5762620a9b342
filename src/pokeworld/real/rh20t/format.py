"""RH20T on-disk format facts: robot configurations, camera serials per role, calibration conventions and
the scene folder name pattern (docs/rh20t.md gives the provenance of each)."""

from __future__ import annotations

import re

ROBOTS: dict[int, str] = {1: "flexiv", 2: "flexiv", 3: "ur5", 4: "ur5", 5: "franka", 6: "kuka", 7: "kuka"}
"""RH20T robot configurations (rh20t_api configs/configs.json, ``conf_num`` -> ``robot``)."""

# Camera serial numbers per configuration and role, each an ORDERED list: the first serial present in a
# scene is used, the next ones are fallbacks (the serial each scene used is recorded in the manifest and
# counted in the report). Roles follow the RH20T authors' own loader (cage-policy/CAGE utils/dataset.py:
# FRONT_CAM / IN_HAND_CAMS / SIDE_CAM / BACK_CAM per cfg); the first "far" serial of each cfg is the "front"
# camera of kpertsch/rh20t_dataset_converter rh20t/cam_definitions.py, whose "overhead" cfg6/7 serial
# 104122060811 the authors list as a BACK camera. In-hand serials also agree with rh20t_api
# configs/configs.json ``in_hand``. docs/rh20t.md has the provenance table. Override per run with
# ``ConvertConfig.camera_serials`` (an explicit list never falls back).
_FRONT_FLEXIV_B = ("037522062165", "104122061850", "f0461559")
_FRONT_UR = ("038522062288", "104122062295", "104422070011", "f0172289")
_FRONT_KUKA = ("104122061018", "104122061330", "f0271510")
_SIDE_B = ("104122063678", "105422061350")
_BACK_B = ("036422060215", "104422070044")
_BACK_UR = ("036422060909", "104122062823")
_SIDE_KUKA = ("037522061512", "104122063633", "104122064161")
_BACK_KUKA = ("104122060811", "104122061602")
CAMERA_ROLES: dict[int, dict[str, tuple[str, ...]]] = {
    1: {"far": ("750612070851", "035622060973", "039422060546", "750612070853"), "close": ("043322070878",),
        "side": ("038522062547",), "back": ("819112070044",)},
    2: {"far": _FRONT_FLEXIV_B, "close": ("104422070042",), "side": _SIDE_B, "back": _BACK_B},
    3: {"far": _FRONT_UR, "close": ("045322071843",), "side": ("104122063550",), "back": _BACK_UR},
    4: {"far": _FRONT_UR, "close": ("045322071843",), "side": ("104122063550",), "back": _BACK_UR},
    5: {"far": _FRONT_FLEXIV_B, "close": ("135122079702", "104422070042"), "side": _SIDE_B, "back": _BACK_B},
    6: {"far": _FRONT_KUKA, "close": ("135122070361", "135122075425"), "side": _SIDE_KUKA, "back": _BACK_KUKA},
    7: {"far": _FRONT_KUKA, "close": ("135122070361", "135122075425"), "side": _SIDE_KUKA, "back": _BACK_KUKA},
}
"""cfg -> role -> ordered candidate serials (first present wins, later ones are fallbacks). Roles: far (front
third-person / global view), close (in-hand wrist camera), side, back; the camera option ``two_view`` means
far + close side by side."""

CAMERA_ROTATION: dict[tuple[int, str], int] = {
    (3, "f0172289"): 90, (4, "f0172289"): 90, (5, "f0461559"): 270, (6, "f0271510"): 270, (7, "f0271510"): 270,
}
"""(cfg, serial) -> image rotation [degrees, PIL convention: counter-clockwise] for cameras mounted sideways, as the
RH20T authors' loader corrects them (cage-policy/CAGE utils/preprocessings.py ``camera_orientation_correction``),
followed by a bottom square crop unless ``crop`` is given. cfg2's f0461559 is rotated only for some users/tasks
there and is left unrotated here (it is the last far fallback of cfg2)."""

CAMERA_OPTIONS = ("far", "close", "two_view", "side", "back")

IN_HAND_CALIB: dict[int, tuple[str, ...]] = {1: ("043322070878",), 2: ("104422070042",), 3: ("045322071843",),
                                            4: ("045322071843",), 5: ("104422070042", "135122079702"),
                                            6: ("135122075425", "135122070361"), 7: ("135122075425", "135122070361")}
"""rh20t_api configs/configs.json ``in_hand`` in its order: the API anchors the base-to-world transform on
``in_hand[0]``'s extrinsics (scene.extrinsics_base_aligned), so the camera-frame F/T fallback does too."""

TCP_CAMERA_ROT: dict[int, tuple[tuple[float, ...], ...]] = {
    1: ((0, -1, 0), (1, 0, 0), (0, 0, 1)), 2: ((0, -1, 0), (1, 0, 0), (0, 0, 1)),
    3: ((1, 0, 0), (0, 1, 0), (0, 0, 1)), 4: ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
    5: ((0, 1, 0), (-1, 0, 0), (0, 0, 1)), 6: ((0, -1, 0), (1, 0, 0), (0, 0, 1)), 7: ((0, -1, 0), (1, 0, 0), (0, 0, 1)),
}
"""Rotation part of rh20t_api configs.json ``tc_mat`` (TCP -> in-hand camera) per cfg (translations are irrelevant
for rotating force/torque vectors)."""

ALIGN_BASE_ROT: dict[int, tuple[tuple[float, ...], ...]] = {
    c: (((-1, 0, 0), (0, -1, 0), (0, 0, 1)) if c in (3, 4) else ((1, 0, 0), (0, 1, 0), (0, 0, 1))) for c in range(1, 8)}
"""Rotation part of rh20t_api configs.json ``align_mat_base`` per cfg (UR5: a 180 degree turn about z)."""

SCENE_RE = re.compile(r"^task_(\d{4})_user_(\d{4})_scene_(\d{4})_cfg_(\d{4})(_human)?$")
