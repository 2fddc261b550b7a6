"""The town rendered into the other datasets' layouts (TUM RGB-D, EuRoC ASL, TartanAir, MIMIR), each
exactly as lossvo's reader of that layout reads it: per layout its camera, clock, platform and files. Frames
and ground truth are evaluated at their own stamps from one trajectory (docs/data.md, "Other layouts")."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from lossvo.data import tartanair, tum
from lossvo.data.layouts import LAYOUTS, check_layout
from lossvo.data.synthetic import platforms, routes
from lossvo.data.synthetic.png import write_png
from lossvo.data.synthetic.render import Renderer
from lossvo.data.synthetic.world import scene, sequence_route
from lossvo.geometry.camera import resized_intrinsics


@dataclass(frozen=True)
class Layout:
    """A dataset layout: native (H, W) pixels, camera and ground-truth rates (Hz; None: a pose a frame),
    the platform that carries the camera, and whether its frames are grey."""

    size: tuple[int, int]
    rate_hz: float
    groundtruth_hz: float | None
    platform: platforms.Platform
    grey: bool = False


SPECS = {
    "tum": Layout(tum.SIZE, 30.0, 100.0, platforms.PLATFORMS["handheld"]),
    "euroc": Layout((480, 752), 20.0, 200.0, platforms.PLATFORMS["flying"], grey=True),
    "tartanair": Layout(tartanair.SIZE, tartanair.RATE_HZ, None, platforms.PLATFORMS["drone"]),
    "mimir": Layout((540, 720), 10.0, 100.0, platforms.PLATFORMS["auv"]),
}

FILES = {
    "kitti": ("{0}", "image_2/*.png", ("calib.txt", "times.txt")),
    "tum": ("rgbd_dataset_freiburg1_synthetic_{0}", "rgb/*.png", ("rgb.txt", "groundtruth.txt")),
    "euroc": (
        "synthetic_{0}",
        "mav0/cam0/data/*.png",
        ("mav0/cam0/data.csv", "mav0/cam0/sensor.yaml", "mav0/state_groundtruth_estimate0/data.csv"),
    ),
    "tartanair": ("synthetic/Easy/P{1:03d}", "image_left/*_left.png", ("pose_left.txt",)),
    "mimir": (
        "SyntheticTown/auv0/track{1}",
        "rgb/cam0/data/*.png",
        ("rgb/cam0/data.csv", "rgb/cam0/sensor.yaml", "pose_groundtruth/data.csv"),
    ),
}
"""Each layout's name of a town sequence (formatted with its two digits and its number), and the frames (a
glob) and other files in the sequence's folder, as a rendering writes them."""

EUROC_K = np.array([[458.654, 0.0, 367.215], [0.0, 457.296, 248.375], [0.0, 0.0, 1.0]])
"""EuRoC cam0's intrinsics at 752x480 (its sensor.yaml)."""
EUROC_DISTORTION = np.array([-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05])
"""EuRoC cam0's radial-tangential (k1, k2, p1, p2)."""
EUROC_T_BS = np.array(
    [
        [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975],
        [0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768],
        [-0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
"""EuRoC cam0's pose in the body (IMU) frame (its sensor.yaml), orthonormalised before use."""
EUROC_BIASES = (-0.002229, 0.020700, 0.076350, -0.012492, 0.547666, 0.068904)
"""Gyroscope (rad/s) and accelerometer (m/s^2) biases of every ground-truth row (V1_01's first)."""
EUROC_HEADER = (
    "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], "
    "v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], b_w_RS_S_x [rad s^-1], "
    "b_w_RS_S_y [rad s^-1], b_w_RS_S_z [rad s^-1], b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], "
    "b_a_RS_S_z [m s^-2]\n"
)
"""The header line of the ground truth data.csv of EuRoC (its columns)."""

MIMIR_K = np.array([[360.0, 0.0, 360.0], [0.0, 360.0, 270.0], [0.0, 0.0, 1.0]])
"""A 90-degree pinhole (AirSim's default) at 720x540, without distortion."""
MIMIR_T_BS = np.eye(4)
"""(4, 4) the camera in the NED body frame (x forward, y right, z down): pitched down by 15 degrees (the
README's front camera), at (0.45, -0.06, 0.0) m."""
MIMIR_T_BS[:3, :3] = Rotation.from_euler("y", -math.radians(15)).as_matrix()
MIMIR_T_BS[:3, 3] = (0.45, -0.06, 0.0)
MIMIR_HEADER = "#timestamp [ns],tx [m],ty [m],tz [m],qw,qx,qy,qz\n"
"""The header line of the ground truth data.csv of MIMIR."""

TUM_START_US = 1_305_031_102_175_304
"""Microseconds: the first frame's nominal stamp (that of freiburg1_xyz)."""
TUM_JITTER_US = 3000
"""Microseconds: frame stamps jitter uniformly by up to this much."""
ASL_START_NS = 1_403_636_579_763_555_584
"""Nanoseconds: the first frame's stamp (that of MH_01_easy)."""
GT_MARGIN_S = 0.1
"""Seconds of ground truth before the first frame and after the last."""


def orthonormal(T: np.ndarray) -> np.ndarray:
    """(4, 4) rigid transform with T's rotation block projected onto SO(3) (SVD)."""
    u, _, vt = np.linalg.svd(T[:3, :3])
    out = T.copy()
    out[:3, :3] = u @ vt
    return out


P4 = np.eye(4)
P4[:3, :3] = tartanair.NED_TO_CAMERA


def ned(T: np.ndarray) -> np.ndarray:
    """Poses (..., 4, 4) in the town's axes -> NED axes (the inverse of tartanair.ned_to_camera)."""
    return P4.T @ T @ P4


def sequence_name(layout: str, sequence: str) -> str:
    """The name a layout's reader knows a town sequence by ("00" -> "rgbd_dataset_freiburg1_synthetic_00")."""
    return FILES[check_layout(layout)][0].format(sequence, int(sequence))


def sequence_paths(layout: str, sequence: str) -> list[str]:
    """The paths under a dataset root that hold a sequence: its folder (and KITTI's poses file)."""
    if layout == "kitti":
        return [f"sequences/{sequence}", f"poses/{sequence}.txt"]
    return [sequence_name(layout, sequence)]


def sequence_complete(root: Path, layout: str, sequence: str, n_frames: int) -> bool:
    """Whether root holds a layout's sequence with its files (KITTI's poses too) and n_frames frames: a
    check of presence, not of content, so that reusing a rendered dataset costs no parsing."""
    folder, *others = (root / path for path in sequence_paths(layout, sequence))
    _, frames, files = FILES[layout]
    required = [folder / f for f in files] + others
    return all(p.is_file() for p in required) and sum(1 for _ in folder.glob(frames)) == n_frames


def camera(layout: str, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """K (3, 3) and distortion (5,) of a layout's frames of size (H, W), as its reader returns them (KITTI's:
    lossvo.data.synthetic.camera)."""
    if layout == "tum":
        return tum.camera(sequence_name("tum", "00"), size=size)
    K = {"euroc": EUROC_K, "tartanair": tartanair.K, "mimir": MIMIR_K}[layout]
    distortion = np.append(EUROC_DISTORTION, 0.0) if layout == "euroc" else np.zeros(5)
    return resized_intrinsics(K, SPECS[layout].size, size), distortion


def mount(layout: str) -> np.ndarray:
    """(4, 4) the camera in the platform's frame, town axes (identity but for MIMIR's pitched camera)."""
    return P4 @ MIMIR_T_BS @ P4.T if layout == "mimir" else np.eye(4)


@dataclass(frozen=True)
class Clock:
    """Integer stamps of frames (N,) and ground truth (M,) (M = 0: a pose a frame) in ticks of unit
    seconds, and the origin (a tick) of the trajectory's time t = (stamp - origin) * unit >= 0."""

    frames: np.ndarray
    groundtruth: np.ndarray
    unit: float
    origin: int

    def seconds(self, stamps: np.ndarray) -> np.ndarray:
        """(N,) trajectory times (s) of integer stamps (N,)."""
        return (np.asarray(stamps, np.int64) - self.origin).astype(np.float64) * self.unit


def clock(layout: str, n_frames: int, rng: np.random.Generator) -> Clock:
    """The stamps of a layout's sequence of n_frames frames. TUM: microseconds, jittered frames, ground truth
    on a 100 us grid (TUM's 4 decimals), a frame stamp on it moved by 1 us. EuRoC and MIMIR: nanoseconds,
    ground truth offset from the frames by 1.234567 ms. TartanAir: frame indices."""
    spec = SPECS[layout]
    k = np.arange(n_frames)
    if layout == "tartanair":
        return Clock(k.astype(np.int64), np.zeros(0, np.int64), 1.0 / spec.rate_hz, 0)
    assert spec.groundtruth_hz is not None
    tick, start = (1e-6, TUM_START_US) if layout == "tum" else (1e-9, ASL_START_NS)
    per_s = round(1 / tick)
    frames = start + np.round(k * per_s / spec.rate_hz).astype(np.int64)
    gt_step = round(per_s / spec.groundtruth_hz)
    if layout == "tum":
        frames += rng.integers(-TUM_JITTER_US, TUM_JITTER_US + 1, n_frames)
        first = (frames[0] - round(GT_MARGIN_S * per_s)) // 100 * 100
    else:
        first = frames[0] - round(GT_MARGIN_S * per_s) + 1_234_567
    count = int((frames[-1] + GT_MARGIN_S * per_s - first) // gt_step) + 1
    groundtruth = first + gt_step * np.arange(count, dtype=np.int64)
    frames += np.isin(frames, groundtruth)
    return Clock(frames, groundtruth, tick, int(first))


def _pose_rows(T: np.ndarray, sep: str, wxyz: bool = False, *columns: np.ndarray) -> list[str]:
    """Per pose of T (M, 4, 4): its position, unit quaternion (x, y, z, w; w first where wxyz), w >= 0,
    and the further columns (M, C), as numbers of 10 significant digits joined by sep."""
    q = Rotation.from_matrix(T[:, :3, :3]).as_quat()
    q *= np.where(q[:, 3:] < 0, -1.0, 1.0)
    values = np.concatenate([T[:, :3, 3], q[:, [3, 0, 1, 2]] if wxyz else q, *columns], 1)
    return [sep.join(f"{v:.10g}" for v in row) for row in values]


def _lines(stamps: list[str] | np.ndarray, values: list[str], sep: str) -> str:
    return "".join(f"{s}{sep}{v}\n" for s, v in zip(stamps, values, strict=True))


def _tum_stamp(us: int, decimals: int) -> str:
    """Microseconds -> 'seconds.fraction' with 6 or 4 decimals (exact: 4 only on a 100 us grid)."""
    sec, rest = divmod(int(us), 1_000_000)
    return f"{sec}.{rest:06d}" if decimals == 6 else f"{sec}.{rest // 100:04d}"


def tum_texts(name: str, c: Clock, gt: np.ndarray) -> tuple[list[str], str, str]:
    """Frame names, rgb.txt and groundtruth.txt of the TUM sequence name (gt: (M, 4, 4) T_w_c at
    c.groundtruth)."""
    stamps = [_tum_stamp(us, 6) for us in c.frames]
    header = f"# file: '{name}.bag'\n# timestamp "
    rgb = f"# color images\n{header}filename\n" + _lines(stamps, [f"rgb/{s}.png" for s in stamps], " ")
    gt_stamps = [_tum_stamp(us, 4) for us in c.groundtruth]
    gt_header = f"# ground truth trajectory\n{header}tx ty tz qx qy qz qw\n"
    return [f"{s}.png" for s in stamps], rgb, gt_header + _lines(gt_stamps, _pose_rows(gt, " "), " ")


def asl_texts(
    c: Clock, sensor: str, header: str, T: np.ndarray, *columns: np.ndarray
) -> tuple[list[str], str, str, str]:
    """Frame names, an ASL camera's data.csv and sensor.yaml (sensor), and a ground-truth data.csv: header,
    then per stamp of c.groundtruth T (M, 4, 4) (quaternion w first) and the further columns (M, C)."""
    names = [f"{ns}.png" for ns in c.frames]
    frames = "#timestamp [ns],filename\n" + _lines(c.frames, names, ",")
    return names, frames, sensor, header + _lines(c.groundtruth, _pose_rows(T, ",", True, *columns), ",")


def euroc_sensor(K: np.ndarray, size: tuple[int, int]) -> str:
    """EuRoC cam0's sensor.yaml for intrinsics K (3, 3) of frames of size (H, W)."""
    T = ", ".join(repr(float(v)) for v in orthonormal(EUROC_T_BS).ravel())
    intrinsics = ", ".join(repr(float(v)) for v in (K[0, 0], K[1, 1], K[0, 2], K[1, 2]))
    distortion = ", ".join(repr(float(v)) for v in EUROC_DISTORTION)
    return (
        "# General sensor definitions.\nsensor_type: camera\ncomment: synthetic VI-Sensor cam0\n\n"
        f"# Sensor extrinsics wrt. the body-frame.\nT_BS:\n  cols: 4\n  rows: 4\n  data: [{T}]\n\n"
        f"# Camera specific definitions.\nrate_hz: {SPECS['euroc'].rate_hz:g}\n"
        f"resolution: [{size[1]}, {size[0]}]\ncamera_model: pinhole\n"
        f"intrinsics: [{intrinsics}] #fu, fv, cu, cv\ndistortion_model: radial-tangential\n"
        f"distortion_coefficients: [{distortion}]\n"
    )


def mimir_sensor(K: np.ndarray, size: tuple[int, int]) -> str:
    """MIMIR's rgb/cam0/sensor.yaml (JSON) for intrinsics K (3, 3) of frames of size (H, W)."""
    sensor = {
        "sensor_type": "camera",
        "comment": "synthetic front camera",
        "T_BS": MIMIR_T_BS.tolist(),
        "rate_hz": SPECS["mimir"].rate_hz,
        "resolution": [size[1], size[0]],
        "camera_model": "pinhole",
        "intrinsics": K.tolist(),
        "distortion_model": "radial-tangential",
        "distortion_coefficients": [0.0] * 5,
    }
    return json.dumps(sensor, indent=2) + "\n"


def write_files(folder: Path, layout: str, frames: list[str], *texts: str) -> list[Path]:
    """Write a layout's files (:data:`FILES`, in its order) with texts into folder; returns the paths of
    its frames, named frames."""
    _, images, files = FILES[layout]
    for name, text in zip(files, texts, strict=True):
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_text(text)
    (folder / images).parent.mkdir(parents=True, exist_ok=True)
    return [(folder / images).parent / name for name in frames]


def _streams(layout: str, sequence: str, seed: int) -> np.random.Generator:
    """The seeded generator of a layout's motion and clock for a sequence (independent of the town's)."""
    return np.random.default_rng(np.random.SeedSequence([seed, int(sequence), 1 + LAYOUTS.index(layout)]))


def route_frames(sequence: str, distance: float, seed: int, spec: routes.RouteSpec) -> int:
    """Route frames (10 Hz car poses) whose path is at least distance metres long."""
    n = 20 + math.ceil(distance / 0.5)
    while True:
        route = sequence_route(sequence, n, seed, spec)
        if np.linalg.norm(np.diff(route[:, :3, 3], axis=0), axis=1).sum() >= distance:
            return n
        n *= 2


def render_sequence(
    root: Path,
    layout: str,
    sequence: str,
    n_frames: int,
    size: tuple[int, int],
    seed: int,
    spec: routes.RouteSpec = routes.DEFAULT_SPEC,
) -> None:
    """Render one town sequence in a layout under the dataset root (its folder :func:`sequence_name`)."""
    lay, rng = SPECS[layout], _streams(layout, sequence, seed)
    c = clock(layout, n_frames, rng)
    t_frames, t_gt = c.seconds(c.frames), c.seconds(c.groundtruth)
    t_end = float(t_gt.max(initial=t_frames[-1]))
    n_route = route_frames(sequence, platforms.max_distance(lay.platform, t_end) + 5.0, seed, spec)
    route, world, noise = scene(sequence, n_route, seed, spec)
    motion = platforms.trajectory(route, lay.platform, rng)
    K, distortion = camera(layout, size)
    if layout == "tum":
        frames, *texts = tum_texts(sequence_name(layout, sequence), c, motion.poses(t_gt))
    elif layout == "euroc":
        T_SB = np.linalg.inv(orthonormal(EUROC_T_BS))  # body poses, velocities by central differences
        ahead, behind = motion.poses(t_gt + 5e-4) @ T_SB, motion.poses(t_gt - 5e-4) @ T_SB
        velocity = (ahead[:, :3, 3] - behind[:, :3, 3]) / 1e-3
        biases = np.broadcast_to(EUROC_BIASES, (len(t_gt), 6))
        T_w_b = motion.poses(t_gt) @ T_SB
        frames, *texts = asl_texts(c, euroc_sensor(K, size), EUROC_HEADER, T_w_b, velocity, biases)
    elif layout == "tartanair":
        frames = [f"{k:06d}_left.png" for k in c.frames]
        texts = ["".join(f"{v}\n" for v in _pose_rows(ned(motion.poses(t_frames)), " "))]
    else:
        frames, *texts = asl_texts(c, mimir_sensor(K, size), MIMIR_HEADER, ned(motion.poses(t_gt)))
    paths = write_files(root / sequence_name(layout, sequence), layout, frames, *texts)
    renderer = Renderer(world, K, *size, distortion=distortion)
    for path, T in zip(paths, motion.poses(t_frames) @ mount(layout), strict=True):
        image = renderer.render(T, noise)
        write_png(path, cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if lay.grey else image)
