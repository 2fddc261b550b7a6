"""``python -m lossvo.motion --layout ...``: the motion table of a dataset in its own layout."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lossvo import motion
from test_layout_datamodule import write_tum


def write_tartanair(root: Path, name: str, steps: np.ndarray, yaw_per_frame: float) -> None:
    """A TartanAir sequence (640x480 black frames, NED poses) driving forward by ``steps`` metres a frame
    while turning right by ``yaw_per_frame`` radians a frame."""
    folder = root / name
    (folder / "image_left").mkdir(parents=True)
    frame = np.zeros((480, 640, 3), np.uint8)
    for k in range(len(steps) + 1):
        cv2.imwrite(str(folder / "image_left" / f"{k:06d}_left.png"), frame)
    yaw = yaw_per_frame * np.arange(len(steps) + 1)
    heading = np.stack([np.cos(yaw), np.sin(yaw), np.zeros_like(yaw)], axis=1)  # NED: x north, y east
    position = np.concatenate([[np.zeros(3)], np.cumsum(steps[:, None] * heading[:-1], axis=0)])
    q = Rotation.from_euler("z", yaw[:, None]).as_quat()  # x y z w, about NED's z (down): a right turn
    rows = np.concatenate([position, q], axis=1)
    (folder / "pose_left.txt").write_text("".join(" ".join(f"{v:.9f}" for v in r) + "\n" for r in rows))


def test_the_table_of_a_tartanair_root(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    write_tartanair(tmp_path, "town/Easy/P000", np.full(6, 0.5), 0.02)
    write_tartanair(tmp_path, "town/Hard/P001", np.array([0.0, 1.0, 2.0]), 0.0)
    assert motion.main([str(tmp_path), "--layout", "tartanair"]) == 0
    out = capsys.readouterr().out.splitlines()
    labels = [line.split("|")[1].strip() for line in out[2:]]
    assert labels == ["all (town/Easy/P000, town/Hard/P001)", "town/Easy/P000", "town/Hard/P001"]
    first, second = (line.split("|") for line in out[3:5])
    assert int(first[2]) == 6 and float(first[3]) == pytest.approx(0.5, abs=5e-4)
    assert float(first[10]) == pytest.approx(0.02, abs=5e-5)  # rotation mean, rad a frame
    assert float(second[3]) == pytest.approx(1.0, abs=5e-4) and second[9].strip() == "33.3 %"
    assert motion.main([str(tmp_path), "--layout", "tartanair", "--sequences", "town/Hard/P001"]) == 0
    assert [line.split("|")[1].strip() for line in capsys.readouterr().out.splitlines()[2:]] == [
        "all (town/Hard/P001)",
        "town/Hard/P001",
    ]


def test_a_tum_sequence_of_another_camera(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """The table reads poses only: a TUM sequence whose name names no Freiburg set-up needs no camera."""
    write_tum(tmp_path / "my_recording", 100.0 + np.arange(12) / 30, 99.99 + np.arange(50) / 100)
    assert motion.main([str(tmp_path), "--layout", "tum"]) == 0
    rows = [line.split("|") for line in capsys.readouterr().out.splitlines()[2:]]
    assert [row[1].strip() for row in rows] == ["all (my_recording)", "my_recording"]
    assert float(rows[1][3]) == pytest.approx(0.1 / 30, abs=5e-4)  # 0.1 m/s at 30 Hz


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--layout", "tum"], "--layout tum: give the dataset root"),
        (["{root}", "--layout", "euroc", "--sequences", "MH_01"], "sequence 'MH_01' not found"),
        (["{root}/missing", "--layout", "tartanair"], "dataset root does not exist"),
        (["{root}", "--layout", "rosbag"], "invalid choice: 'rosbag'"),
    ],
)
def test_bad_input_is_one_line(args: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture
                               ) -> None:  # fmt: skip
    with pytest.raises(SystemExit) as exit_info:
        motion.main([a.format(root=tmp_path) for a in args])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
