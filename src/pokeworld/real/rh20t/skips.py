"""The reason codes a scene can be skipped with and the exception that carries one."""

from __future__ import annotations

from ...errors import DataError

SKIP_REASONS = {
    "human_demo": "a *_human demonstration folder (no robot streams)",
    "other_cfg": "scene of a different robot configuration than --cfg",
    "unknown_cfg": "configuration number outside RH20T's cfg1-cfg7",
    "missing_metadata": "metadata.json absent",
    "bad_metadata": "metadata.json unreadable or without an integer rating",
    "low_rating": "rating below min_rating (RH20T: <= 1 marks failed / stopped)",
    "missing_calib": "metadata calib absent or -1 (or calib folder absent when required)",
    "missing_stream": "a required transformed/*.npy or timestamps.npy file is absent",
    "camera_frame_ft": "force_torque_base.npy absent; the camera-frame force_torque.npy is present but could not be "
                       "rotated into the base frame (ft_camera_fallback off, or calibration extrinsics / tcp absent)",
    "bad_stream": "a stream file cannot be unpickled or has the wrong structure / shape",
    "unsafe_pickle": "a pickled .npy file (stream, camera timestamps or calibration) references a global the "
                     "restricted unpickler does not admit (e.g. os.system) or rewrites a numpy dtype's state, refused "
                     "before anything in it ran; or the child process unpickling it was killed by a signal or timed "
                     "out",
    "special_file": "metadata.json, a pickled .npy, a video or a frame is not a regular file (a FIFO, device, "
                    "socket or directory), which could hang the conversion; never opened for reading",
    "outside_root": "a file or the calibration folder resolves outside the dataset root (a symlink leading out, "
                    "or a metadata calib value with '..' or an absolute path)",
    "huge_image": "a frame's header (image) or video stream declares more pixels than MAX_FRAME_PIXELS; refused "
                  "before decoding",
    "nan_stream": "more than max_bad_record_fraction of a stream's records are non-finite (isolated ones are dropped "
                  "and counted instead)",
    "zero_tcp": "more than max_bad_record_fraction of the TCP records are all zeros (pose not logged)",
    "overflow_stream": "more than max_bad_record_fraction of a stream's records hold overflowed values (|x| > 1e6)",
    "bad_units": "most TCP positions beyond max_abs_pos_m (millimetres instead of metres?) or most quaternions "
                 "non-unit (wrong order / units?)",
    "bad_timestamps": "timestamps not 13-digit milliseconds or streams do not overlap in time",
    "stream_gap": "a numeric stream has a gap longer than max_gap_s inside the scene",
    "missing_camera": "no camera folder for the requested role",
    "empty_video": "color video / image folder has no frames",
    "unreadable_video": "color video or image cannot be decoded",
    "truncated_video": "fewer decoded frames than timestamps",
    "frame_count_mismatch": "more decoded frames than timestamps",
    "frame_gap": "no camera frame within frame_tolerance_s of a grid time",
    "too_short": "fewer than episode_steps + 1 grid steps",
    "unexpected_error": "an unanticipated exception while reading the scene (message recorded)",
}
"""Every reason code a scene can be skipped with (reported in conversion_report.json)."""


class SceneSkip(DataError):
    """A scene that cannot be converted; ``reason`` is a key of :data:`SKIP_REASONS`."""

    def __init__(self, reason: str, message: str, cacheable: bool = True):
        assert reason in SKIP_REASONS, reason
        super().__init__(f"{reason}: {message}")
        self.reason, self.message = reason, message
        self.cacheable = cacheable
        """False when a rerun could decide otherwise: the skip is not cached."""
