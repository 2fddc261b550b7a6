"""Route families: the generator produces the motion each family asks for, the default mixes span real
driving, and impossible parameters are refused with one line naming them."""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path

import numpy as np
import pytest

from lossvo import motion as motion_cli
from lossvo.console import UserError
from lossvo.data import motion, synthetic
from lossvo.data.synthetic import cli as synthetic_cli
from lossvo.data.synthetic import routes
from lossvo.table_render import Rows, markdown

LONG = 4000  # frames: enough manoeuvres of every kind for statistics


def family_route(name: str, n: int = LONG, seed: int = 0) -> np.ndarray:
    return routes.make_route(np.random.default_rng(seed), n, {name: 1.0})


def relative(poses: np.ndarray) -> np.ndarray:
    return np.linalg.inv(poses[:-1]) @ poses[1:]


@pytest.mark.parametrize("name", list(routes.FAMILIES))
def test_each_family_drives_within_its_ranges(name: str) -> None:
    family = routes.FAMILIES[name]
    poses = family_route(name)
    speed, rotation = motion.frame_motion(poses)
    moving = speed > motion.STANDING
    # cruise speeds drawn from the family's range, with ~3 % speed noise on top
    assert np.percentile(speed[moving], 95) <= family.cruise[1] * 1.08
    assert speed.max() <= family.cruise[1] * 1.15
    assert np.percentile(speed[moving], 50) >= min(family.turn_speed[0], family.cruise[0]) * 0.9
    standing = (~moving).mean()
    assert (standing > 0.02) if family.stop > 0.2 else (standing < 0.05), standing
    if family.stop == 0:
        assert standing == 0.0
    # pitch and roll stay within the stated bound, the camera height within the hills' amplitude
    tilt = np.arccos(np.clip(poses[:, 1, 1], -1, 1))
    assert tilt.max() <= 2 * routes.MAX_TILT + 1e-9
    height = -poses[:, 1, 3]
    assert np.abs(height).max() <= family.hill * 2 + 0.06
    assert np.isfinite(rotation).all() and rotation.max() < 0.2


@pytest.mark.parametrize("name", list(routes.FAMILIES))
def test_turns_have_their_planned_angle_and_radius(name: str) -> None:
    family = routes.FAMILIES[name]
    plan = routes.plan_route(np.random.default_rng(3), LONG, {name: 1.0})
    speed = routes.speed_profile(plan.target)
    rate = routes.yaw_rates(speed, plan.events)
    turns = [e for e in plan.events if e[2] == "turn" and e[1] <= LONG]
    assert turns, "no turn in a long route"
    lo, hi = (math.radians(a) for a in family.turn_angle)
    for start, end, _, angle in turns:
        assert lo - 1e-9 <= abs(angle) <= hi + 1e-9
        np.testing.assert_allclose(rate[start:end].sum(), angle, rtol=1e-9)
        radius = speed[start:end].sum() / abs(angle)  # arc length over angle: the mean radius
        assert family.turn_radius[0] * 0.6 <= radius <= family.turn_radius[1] * 1.4, (radius, start)
    lanes = [e for e in plan.events if e[2] == "lane"]
    for start, end, _, width in lanes:
        heading = np.cumsum(rate[start:end])
        np.testing.assert_allclose((speed[start:end] * heading).sum(), width, rtol=1e-6)
        assert abs(heading[-1]) < 1e-9  # back on the original heading


def test_a_standing_car_does_not_move_at_all() -> None:
    poses = family_route("stop_and_go", 1500)
    rel = relative(poses)
    speed, _ = motion.frame_motion(poses)
    stopped = speed < 1e-12
    standing = stopped & np.roll(stopped, 1) & np.roll(stopped, -1)  # the suspension settles in a frame
    assert standing.sum() > 50
    np.testing.assert_allclose(rel[standing], np.broadcast_to(np.eye(4), rel[standing].shape), atol=1e-9)


def test_speed_profile_respects_the_acceleration_and_braking_limits() -> None:
    target = np.concatenate([np.full(50, 1.2), np.zeros(20), np.full(100, 0.8)])
    v = routes.speed_profile(target)
    assert (v <= target + 1e-12).all() and (v[50:70] == 0).all()
    dv = np.diff(v)
    assert dv.max() <= routes.ACCEL + 1e-12 and dv.min() >= -routes.BRAKE - 1e-12
    assert v[-1] == pytest.approx(0.8)


def pooled(mix: dict[str, float], frames: int, n_routes: int) -> dict[str, float]:
    moves = [
        motion.frame_motion(routes.make_route(np.random.default_rng(s), frames, mix)) for s in range(n_routes)
    ]
    return motion.statistics(np.concatenate([m[0] for m in moves]), np.concatenate([m[1] for m in moves]))


def test_the_training_mix_spans_real_driving() -> None:
    """Speeds from standstill to ~1.4 m/frame, real KITTI's mean (0.82) and rotation RMS (0.022 rad) in
    range: the stated tolerances are mean speed 0.6-1.0 m/frame, rotation RMS 0.01-0.035 rad/frame."""
    stats = pooled(routes.TRAINING_MIX, 600, 12)
    assert 0.6 <= stats["speed mean"] <= 1.0, stats
    assert 1.3 <= stats["speed max"] <= 1.55, stats
    assert stats["speed p5"] < 0.45, stats
    assert 0.002 <= stats["standing"] <= 0.1, stats
    assert 0.01 <= stats["rot RMS"] <= 0.035, stats


def test_the_unseen_mix_is_slower_and_faster_than_training_and_stops_more() -> None:
    train, unseen = pooled(routes.TRAINING_MIX, 450, 8), pooled(routes.UNSEEN_MIX, 450, 8)
    assert unseen["standing"] > train["standing"]
    assert unseen["speed p5"] < train["speed p5"]
    assert unseen["speed p95"] > train["speed p95"] - 0.05


def test_unseen_sequences_drive_only_families_that_no_other_sequence_drives() -> None:
    unseen = {f for s in routes.UNSEEN_SEQUENCES for f in routes.DEFAULT_SPEC.mix(s)}
    others = {
        f for s in synthetic.SEQUENCES if s not in routes.UNSEEN_SEQUENCES for f in routes.DEFAULT_SPEC.mix(s)
    }
    assert unseen and not unseen & others
    for s in routes.UNSEEN_SEQUENCES:
        plan = routes.plan_route(np.random.default_rng(0), 450, routes.DEFAULT_SPEC.mix(s))
        assert set(plan.family) <= unseen


def test_unknown_family_lists_the_families() -> None:
    expected = "unknown route family 'motorway': expected one of town, residential, arterial"
    with pytest.raises(UserError, match=expected):
        routes.make_route(np.random.default_rng(0), 10, {"motorway": 1.0})


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"cruise": (-0.5, 1.0)}, "cruise must be a range 0 < low <= high"),
        ({"turn_radius": (0.0, 10.0)}, "turn_radius must be a range 0 < low <= high"),
        ({"turn_speed": (0.5, 0.2)}, "turn_speed must be a range"),
        ({"stop": 1.5}, "stop must be a probability"),
        ({"turn": 0.7, "stop": 0.5}, "turn \\+ lane_change \\+ stop must be <= 1"),
        ({"hill": -1.0}, "hill must be in"),
    ],
)
def test_impossible_family_parameters_name_the_parameter(change: dict, message: str) -> None:
    with pytest.raises(UserError, match=message):
        dataclasses.replace(routes.FAMILIES["town"], **change)


def test_bad_mix_weights() -> None:
    with pytest.raises(UserError, match="non-negative weights"):
        routes.check_mix({"town": -1.0})
    assert routes.check_mix({"town": 2.0, "country": 2.0}) == {"town": 0.5, "country": 0.5}


def families_markdown() -> str:
    """The route families and the sequences' mixes as the Markdown table docs/data.md shows."""

    def span(bounds: tuple[float, float], digits: int = 2) -> str:
        return f"{bounds[0]:.{digits}f}-{bounds[1]:.{digits}f}"

    head = [
        "family",
        "driving",
        "cruise m/frame",
        "straights m",
        "turns",
        "turn angle °",
        "turn radius m",
        "lane changes",
        "stops (frames)",
        "hills m",
        "camber rad",
        "sequences",
    ]
    rows = []
    for f in routes.FAMILIES.values():
        drives = [s for s, mix in routes.MIXES.items() if mix.get(f.name, 0) > 0]
        row = [
            f"`{f.name}`",
            f.description,
            span(f.cruise),
            span(f.straight, 0),
            f"{f.turn:.0%}",
            span(f.turn_angle, 0),
            span(f.turn_radius, 0),
            f"{f.lane_change:.0%}",
            f"{f.stop:.0%} ({f.stop_frames[0]}-{f.stop_frames[1]})" if f.stop else "-",
            f"{f.hill:.2f}" if f.hill else "-",
            f"{f.camber:.3f}" if f.camber else "-",
            f"{drives[0]}-{drives[-1]}" if drives else "-",
        ]
        rows.append(row)
    return markdown(Rows(head, rows))


def test_docs_show_the_route_families_table() -> None:
    text = (Path(__file__).parents[1] / "docs" / "data.md").read_text()
    table = text.split("<!-- route-families:start -->\n", 1)[1].split("\n<!-- route-families:end -->", 1)[0]
    assert table == families_markdown()


def town_sequence(root: Path, frames: int) -> np.ndarray:
    """A KITTI-layout root holding sequence 00's pose file only: a town route of ``frames`` poses."""
    (root / "sequences" / "00").mkdir(parents=True)
    (root / "poses").mkdir()
    poses = family_route("town", frames)
    np.savetxt(root / "poses" / "00.txt", poses[:, :3].reshape(len(poses), 12))
    return poses


def test_motion_command_prints_a_row_per_split_and_sequence(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    poses = town_sequence(tmp_path, 200)
    assert motion_cli.main([str(tmp_path), "--train", "00", "--val", "", "--test", "00", "--unseen", ""]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("| split / sequence | pairs | speed mean")
    labels = [line.split("|")[1].strip() for line in out[2:]]
    assert labels == ["train (00)", "test (00)", "00"]
    speed, rotation = motion.frame_motion(poses)
    cells = out[-1].split("|")
    assert float(cells[3]) == pytest.approx(speed.mean(), abs=5e-4)
    assert float(cells[11]) == pytest.approx(np.sqrt((rotation**2).mean()), abs=5e-5)


def test_motion_command_refuses_a_named_sequence_without_poses(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    town_sequence(tmp_path, 50)
    with pytest.raises(SystemExit) as exit_info:
        motion_cli.main([str(tmp_path), "--train", "00,99"])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"python -m lossvo.motion: error: --train: {tmp_path} has no poses file for 99 (poses/NN.txt)"
    ]
    assert motion_cli.main([str(tmp_path)]) == 0  # the default splits' missing sequences (01-12) are left out


def test_motion_command_bad_root_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit) as exit_info:
        motion_cli.main([str(tmp_path / "missing")])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "dataset root does not exist" in err[0]


def test_route_spec_adds_families_and_mixes_that_the_routes_follow() -> None:
    crawl = {"description": "walking pace", "cruise": [0.1, 0.12], "straight": [5, 10], "turn": 0.0,
             "turn_angle": [10, 20], "turn_radius": [5, 10], "turn_speed": [0.1, 0.1]}  # fmt: skip
    spec = routes.route_spec(
        families={"crawl": crawl, "town": {"stop": 0.0}}, mixes={"11": {"crawl": 1.0}, 3: {"town": 1.0}}
    )
    assert spec.mix("11") == {"crawl": 1.0} and spec.mix("03") == {"town": 1.0}
    assert spec.mix("00") == routes.TRAINING_MIX and spec.families["town"].stop == 0.0
    speed, _ = motion.frame_motion(synthetic.sequence_route("11", 200, spec=spec))
    assert speed.max() <= 0.12 * 1.15
    default = synthetic.sequence_route("11", 200)
    assert not np.allclose(default, synthetic.sequence_route("11", 200, spec=spec))


@pytest.mark.parametrize(
    ("families", "mixes", "message"),
    [
        (
            None,
            {"11": {"motorway": 1.0}},
            "data.sources.synthetic.route_mixes.11: unknown route family 'motorway': expected one of",
        ),
        (
            None,
            {"11": {"town": "a lot"}},
            "data.sources.synthetic.route_mixes.11: route mix: expected non-negative weights",
        ),
        (
            {"town": {"speed": 1.0}},
            None,
            "data.sources.synthetic.route_families.town: unknown parameter 'speed'",
        ),
        (
            {"crawl": {"cruise": [0.1, 0.2]}},
            None,
            "data.sources.synthetic.route_families.crawl: a new family needs description",
        ),
        (
            {"town": {"turn_radius": [0, 10]}},
            None,
            "route family 'town': turn_radius must be a range 0 < low",
        ),
        ({"town": 3}, None, "data.sources.synthetic.route_families.town: expected a mapping of parameters"),
    ],
)
def test_bad_route_config_names_the_key(families, mixes, message: str) -> None:
    with pytest.raises(UserError, match=re.escape(message)):
        routes.route_spec(families, mixes, prefix="data.sources.synthetic.")


@pytest.mark.slow
def test_a_changed_route_spec_renders_the_dataset_again(tmp_path: Path) -> None:
    root = synthetic.generate(tmp_path, ["11"], 4, height=32, width=96, progress=False, workers=1)
    before = (root / "poses" / "11.txt").read_text()
    spec = routes.route_spec(mixes={"11": {"expressway": 1.0}})
    synthetic.ensure_dataset(root, ["11"], 4, height=32, width=96, progress=False, workers=1, spec=spec)
    assert (root / "poses" / "11.txt").read_text() != before
    manifest = synthetic.read_manifest(root)
    assert manifest is not None and manifest["routes"]["mixes"]["11"] == {"expressway": 1.0}


@pytest.mark.slow
def test_cli_mix_and_its_errors(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    args = ["--out", str(tmp_path), "--sequences", "11", "--frames", "3", "--height", "32", "--width", "96"]
    assert synthetic_cli.main([*args, "--quiet", "--mix", "11=expressway:2+stop_and_go"]) == 0
    assert synthetic.read_manifest(tmp_path)["routes"]["mixes"]["11"] == {
        "expressway": pytest.approx(2 / 3), "stop_and_go": pytest.approx(1 / 3)}  # fmt: skip
    bad_mixes = [
        ("11=motorway", "--mix 11=motorway: unknown route family 'motorway'"),
        ("11", "--mix: expected NN=FAMILY"),
        ("11=town:x", "weight of 'town' is not a number"),
    ]
    for bad, message in bad_mixes:
        with pytest.raises(SystemExit):
            synthetic_cli.main([*args, "--mix", bad])
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0], err
