"""RH20T real-robot scenes -> a pokeworld store (``pokeworld rh20t-convert ROOT --cfg 7``).

Pipeline, one scene at a time (docs/rh20t.md lists every format fact and choice):

1. **scan** ``ROOT`` (an ``RH20T_cfgN`` folder or a folder holding them) for scene folders
   ``task_NNNN_user_NNNN_scene_NNNN_cfg_NNNN``; ``*_human`` demonstration folders, other
   configurations and unknown configurations are skipped with a counted reason.
2. **read** ``metadata.json`` (rating, calibration id, start/finish time), the pickled
   ``transformed/{tcp_base,force_torque_base,gripper}.npy`` dicts and the chosen camera(s)
   (``cam_<serial>/color.mp4`` + ``timestamps.npy``, or extracted ``cam_<serial>/color/<ts>.jpg``).
3. **resample** every numeric stream onto a regular ``hz`` grid by linear interpolation
   (quaternions: hemisphere-aligned lerp + renormalisation) and take the nearest camera frame;
   crop/resize to ``image_size`` grayscale. The result is cached per scene
   (``<out>.cache/<key>/<scene>.npz``, written atomically), so an interrupted run resumes.
4. **assemble**: fixed-length chunks of ``episode_steps`` steps, scene-level and held-out-task
   splits, per-column 0.1/99.9-percentile clipping + whitening with train-only statistics,
   labels (raw force, contact onset, TCP pose), then :func:`pokeworld.data.save`.

Pickled ``.npy`` files are read by :mod:`pokeworld.real.safe_pickle`'s restricted unpickler (a pickle naming
anything but numpy arrays and python containers, or rewriting a numpy dtype's state, skips the scene as
``unsafe_pickle`` before it runs), in a child process (:mod:`pokeworld.real.npy_child`: a child killed by a signal
or timing out skips the scene as ``unsafe_pickle`` too). Every file read must be a regular file inside the dataset
root (:mod:`.files`: FIFOs and devices skip as ``special_file``, symlinks or a metadata ``calib`` leading out as
``outside_root``), and a frame declaring more than ``MAX_FRAME_PIXELS`` skips as ``huge_image`` before decoding.
Isolated bad records (NaN, overflowed ~1e36, all-zero TCP, out-of-range values) are dropped and
counted; a camera role falls back along its ordered serial list, then (external roles only) to another
external camera present in the scene; a missing base-frame F/T file is
replaced by the camera-frame one rotated through the calibration. Any other defect of one scene
(missing stream / calibration / camera, an unusable stream, empty or truncated video, unknown
configuration...) skips that scene with a reason code that is counted in
``<out>/conversion_report.json`` (with the cameras used, the dropped records and the F/T sources);
a run never stops half-way because of one bad scene and never writes an array it could not verify.
``max_scenes`` draws a seeded, task-stratified, nested random subset for scaling studies.

Streams written to the store (``manifest["columns"]`` names every column):

* ``proprio`` (8): TCP position in the robot base frame [m] (x, y, z), TCP orientation quaternion
  (w, x, y, z), gripper opening width [m];
* ``touch`` (6): zeroed (tared) force [N] and torque [N m] in the robot base frame;
* ``actions`` (7): TCP position delta [m], rotation delta as a rotation vector of
  ``q_{t+1} * conj(q_t)`` (base frame) [rad], gripper width delta [m], between consecutive grid steps.

``proprio``/``touch``/``actions`` are clipped and whitened; the raw physical values stay
available as ``labels`` (``force``, ``torque``, ``tcp_pos``, ``tcp_quat``, ``gripper_width``).

Modules, in pipeline order: :mod:`.format` (RH20T layout facts), :mod:`.skips` (skip reasons), :mod:`.config`,
:mod:`.folders` (scene names, scan), :mod:`.files` (which files may be read), :mod:`.records` (numeric streams),
:mod:`.rotations`, :mod:`.calibration` (camera-frame F/T), :mod:`.cameras` (serial choice), :mod:`.video` (frames),
:mod:`.scene` (one scene),
:mod:`.cache`, :mod:`.splits`, :mod:`.assembly` (the dataset) and :mod:`.convert` (the command).
"""

from __future__ import annotations

from .assembly import (
                       ACTION_COLUMNS,
                       PROPRIO_COLUMNS,
                       TOUCH_COLUMNS,
                       apply_whiten,
                       assemble,
                       contact_onset,
                       robust_whiten_stats,
                       tcp_actions,
)
from .cache import PIPELINE_VERSION, cache_dir, convert_scene_cached
from .calibration import base_to_camera_rotations, calib_tcp_rotation
from .cameras import (
                       EXTERNAL_ROLES,
                       IN_HAND_SERIALS,
                       camera_serials,
                       other_external_serials,
)
from .config import PRESETS, ConvertConfig, content_config, make_config, out_dir
from .convert import corpus_source, run
from .files import calibration_folder, dataset_file, open_dataset_file, read_dataset_file, scene_root
from .folders import SceneRef, check_scene_name, parse_scene_name, scan
from .format import (
                       ALIGN_BASE_ROT,
                       CAMERA_OPTIONS,
                       CAMERA_ROLES,
                       CAMERA_ROTATION,
                       IN_HAND_CALIB,
                       ROBOTS,
                       SCENE_RE,
                       TCP_CAMERA_ROT,
)
from .records import (
                       BAD_RECORD_KINDS,
                       OVERFLOW_ABS,
                       classify_records,
                       clean_records,
                       load_pickled_dict,
                       load_untrusted_npy,
                       read_ft,
                       read_gripper,
                       read_records,
)
from .rotations import (
                       align_quaternions,
                       euler_sxyz_to_mat,
                       quat_mul,
                       quat_to_mat,
                       quat_to_rotvec,
                       rotvec_to_mat,
)
from .scene import MAX_METADATA_BYTES, interp_columns, process_scene, read_metadata
from .skips import SKIP_REASONS, SceneSkip
from .splits import split_scenes, stratified_indices, stratified_subset
from .video import MAX_FRAME_PIXELS, MAX_IMAGE_FILE_BYTES, check_image_header, crop_resize, read_camera

__all__ = [
    "ConvertConfig", "PRESETS", "make_config", "run", "scan", "parse_scene_name", "process_scene", "SceneSkip",
    "SKIP_REASONS", "CAMERA_ROLES", "CAMERA_ROTATION", "ROBOTS", "contact_onset", "split_scenes", "stratified_subset",
    "clean_records", "base_to_camera_rotations", "BAD_RECORD_KINDS",
    # the names above are the single module's former __all__; the rest stay importable from here as before
    "ACTION_COLUMNS", "ALIGN_BASE_ROT", "CAMERA_OPTIONS", "EXTERNAL_ROLES", "IN_HAND_CALIB", "IN_HAND_SERIALS",
    "OVERFLOW_ABS", "PIPELINE_VERSION", "PROPRIO_COLUMNS", "SCENE_RE", "TCP_CAMERA_ROT", "TOUCH_COLUMNS", "SceneRef",
    "align_quaternions", "apply_whiten", "assemble", "cache_dir", "calib_tcp_rotation", "camera_serials",
    "check_scene_name", "classify_records", "content_config", "convert_scene_cached", "corpus_source", "crop_resize",
    "euler_sxyz_to_mat", "interp_columns", "load_pickled_dict", "other_external_serials", "out_dir", "quat_mul",
    "quat_to_mat", "quat_to_rotvec", "read_camera", "read_ft", "read_gripper", "read_records", "robust_whiten_stats",
    "rotvec_to_mat", "stratified_indices", "tcp_actions",
    "MAX_FRAME_PIXELS", "MAX_IMAGE_FILE_BYTES", "MAX_METADATA_BYTES", "calibration_folder", "check_image_header",
    "dataset_file", "load_untrusted_npy", "open_dataset_file", "read_dataset_file", "read_metadata", "scene_root",
]
