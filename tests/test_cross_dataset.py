"""Training and evaluation across dataset layouts, on the synthetic town written in each layout: a
fast_dev_run on each dataset (its own reader, undistortion, grey frames, K), and a network trained on the
KITTI layout evaluated on the TUM, EuRoC and TartanAir layouts from its checkpoint alone."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from helpers import check_ape_against_evo, eval_main, fit
from lossvo.data import synthetic
from lossvo.evaluation import baselines
from lossvo.evaluation.job_folder import DataRecord
from test_train import compose_train, tiny_overrides

LAYOUTS = ("tum", "euroc", "tartanair", "mimir")
SCALE = 0.14
"""Frames of about 90x67 pixels (105x67 for EuRoC)."""


@pytest.fixture(scope="module")
def layouts(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Sequences 00 and 01 of the synthetic town, 14 frames each, in every other layout."""
    root = tmp_path_factory.mktemp("layouts")
    for layout in LAYOUTS:
        synthetic.generate(root / layout, ("00", "01"), frames=14, layout=layout, scale=SCALE, progress=False)
    return {layout: root / layout for layout in LAYOUTS}


def data_overrides(layout: str, root: Path, cache: Path) -> list[str]:
    """Train on the layout's 00, validate and test on its 01, at 64x96 pixels."""
    train, test = (synthetic.sequence_name(layout, s) for s in ("00", "01"))
    return [
        f"data={layout}",
        f"data.sources.{layout}.root={root}",
        f"data.frames.cache_dir={cache}",
        f"data.splits.train=[{train}]",
        f"data.splits.val=[{test}]",
        f"data.splits.test=[{test}]",
        "data.frames.height=64",
        "data.frames.width=96",
        "data.windows.seq_len=3",
        "data.windows.batch_size=4",
        "data.loader.num_workers=0",
        f"data.sources.{layout}.keep_every=1",
    ]


@pytest.mark.slow
@pytest.mark.parametrize("layout", LAYOUTS)
def test_fast_dev_run_on_each_layout(layouts: dict[str, Path], layout: str, tmp_path: Path) -> None:
    model = ["model.width_mult=0.0625", "model.hidden_size=16", "trainer.log_every_n_steps=1"]
    cfg = compose_train([*data_overrides(layout, layouts[layout], tmp_path / "cache"), *model,
                         "+trainer.fast_dev_run=1"], tmp_path / "run")  # fmt: skip
    metrics = fit(cfg)
    assert {"train/loss", "val/loss", "val/score"} <= set(metrics)
    assert all(torch.isfinite(torch.tensor(v)) for v in metrics.values())


@pytest.mark.slow
def test_flowvo_fast_dev_run_on_distorted_grey_frames(layouts: dict[str, Path], tmp_path: Path) -> None:
    """EuRoC: grey frames, radial-tangential distortion; FlowVO reads the flow of the undistorted frames and
    their K."""
    network = ["model=flowvo", "model.channels=[8,8,8,8]", "model.hidden=8", "data.windows.seq_len=2"]
    overrides = [*data_overrides("euroc", layouts["euroc"], tmp_path / "cache"), *network,
                 "+trainer.fast_dev_run=1"]  # fmt: skip
    metrics = fit(compose_train(overrides, tmp_path / "run"))
    assert all(torch.isfinite(torch.tensor(v)) for v in metrics.values())
    assert list((tmp_path / "cache").rglob("*.flow-dis-medium-x1.5-s1.npy"))


@pytest.fixture(scope="module")
def kitti_run(tiny_kitti: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One epoch on the tiny synthetic KITTI-layout dataset; the run folder."""
    tmp = tmp_path_factory.mktemp("kitti_run")
    fit(compose_train([*tiny_overrides(tiny_kitti, tmp / "cache"), "trainer.max_epochs=1"], tmp / "run"))
    return tmp / "run"


@pytest.mark.slow
@pytest.mark.parametrize("layout", ["tum", "euroc", "tartanair"])
def test_a_kitti_trained_network_evaluates_on_another_layout_from_its_checkpoint(
    kitti_run: Path, layouts: dict[str, Path], layout: str, tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture,
) -> None:  # fmt: skip
    """``python -m lossvo.eval ckpt_path=... data=<layout> data.sources.<layout>.root=R
    data.splits.test=[...]``: the frame size, seq_len and normalisation come from the checkpoint;
    results.json names both datasets; the TUM files beside the estimate reproduce its APE with evo."""
    name = synthetic.sequence_name(layout, "01")
    out = tmp_path / "eval"
    args = [
        f"ckpt_path={kitti_run / 'checkpoints' / 'best.ckpt'}",
        f"data={layout}",
        f"data.sources.{layout}.root={layouts[layout]}",
        f"data.splits.test=[{name}]",
        f"data.frames.cache_dir={tmp_path / 'cache'}",
        "data.loader.num_workers=0",
        "device=cpu",
        f"hydra.run.dir={out}",
    ]
    status, err = eval_main(args, monkeypatch, capsys)
    assert status == 0, err
    results = json.loads((out / "results.json").read_text())
    data = results["data"]
    assert data["layout"] == layout and data["train_layout"] == "kitti"
    assert (data["height"], data["width"], data["seq_len"]) == (64, 96, 3)  # the checkpoint's
    assert list(results["sequences"]) == [name]
    stem = name.replace("/", "_")
    entry = results["sequences"][name]
    assert entry["trajectory"] == f"trajectories/{stem}.txt"
    assert entry["ground_truth"] == str((out / "trajectories" / f"{stem}_gt.tum").resolve())
    check_ape_against_evo(out / "trajectories", stem, entry["ape"]["trans"]["rmse"], entry["frames"])
    # the camera the network saw: the layout's K, resized to the checkpoint's 64x96, recorded per sequence
    K = np.array(entry["K"])
    assert K.shape == (3, 3) and K[2].tolist() == [0, 0, 1]
    trained = torch.load(kitti_run / "checkpoints" / "best.ckpt", weights_only=True)
    training_K = trained["data"]["intrinsics"]
    assert sorted(training_K) == ["00", "01"] and not np.allclose(K, training_K["00"])


# --------------------------------------------------------------------------------------------------
# Several datasets in one run
# --------------------------------------------------------------------------------------------------


def multi_overrides(tiny_kitti: Path, layouts: dict[str, Path], cache: Path) -> list[str]:
    """data=multi: the tiny KITTI-layout dataset (00, 01; validated on 02) and the TUM layout (00; tested on
    01)."""
    tum_train, tum_test = (synthetic.sequence_name("tum", s) for s in ("00", "01"))
    return [
        "data=multi",
        f"data.frames.cache_dir={cache}",
        "data.frames.height=64",
        "data.frames.width=96",
        "data.windows.seq_len=3",
        "data.windows.batch_size=4",
        "data.loader.num_workers=0",
        f"data.sources.kitti.root={tiny_kitti}",
        f"data.sources.tum.root={layouts['tum']}",
        "data.sources.tum.keep_every=1",
        f"data.splits.train=[kitti/00,kitti/01,tum/{tum_train}]",
        "data.splits.val=[kitti/02]",
        f"data.splits.test=[kitti/02,tum/{tum_test}]",
        "model.width_mult=0.0625",
        "model.hidden_size=16",
        "trainer.max_epochs=1",
    ]


@pytest.mark.slow
def test_one_run_trains_on_two_datasets_and_evaluates_each(
    tiny_kitti: Path, layouts: dict[str, Path], tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture,
) -> None:  # fmt: skip
    """Windows of both datasets in the training set, each with its own K; every test sequence of each
    evaluated, named <dataset>/<sequence>, with its TUM files."""
    from hydra.utils import instantiate

    cfg = compose_train(multi_overrides(tiny_kitti, layouts, tmp_path / "cache"), tmp_path / "run")
    dm = instantiate(cfg.data, _convert_="all")
    dm.prepare_data()
    dm.setup()
    tum_test = f"tum/{synthetic.sequence_name('tum', '01')}"
    assert list(dm.splits["train"]) == ["kitti/00", "kitti/01", f"tum/{synthetic.sequence_name('tum', '00')}"]
    assert dm.evaluated == ["kitti/02", tum_test]
    Ks = {tuple(np.round(K.numpy().ravel(), 4)) for K in dm.datasets["train"].intrinsics}
    assert len(Ks) == 2  # KITTI's camera and freiburg1's (undistorted), each resized to 64x96
    starts = dm.datasets["train"].index[:, 0]
    assert set(starts.tolist()) == {0, 1, 2}  # windows from every training sequence of both datasets
    # the car's camera gives metric scale a cue, the handheld TUM camera does not: one flag a window
    assert [bool(m) for m in dm.datasets["train"].metric] == [True, True, False]
    dataset = dm.datasets["train"]
    flags = torch.stack([dataset[i]["metric"] for i in range(len(dataset))])
    assert torch.equal(flags, torch.from_numpy(starts < 2))
    fit(cfg)
    results = json.loads((tmp_path / "run" / "results.json").read_text())
    assert list(results["sequences"]) == ["kitti/02", tum_test]
    assert results["data"]["layout"] == "multi"
    assert [results["sequences"][n]["metric_scale"] for n in ("kitti/02", tum_test)] == [True, False]
    sources = results["data"]["train_sources"]  # each dataset's reading, for the baselines' training split
    assert sources == results["data"]["sources"]
    assert {k: (v["layout"], v["keep_every"]) for k, v in sources.items()} == {
        "kitti": ("kitti", 1),
        "tum": ("tum", 1),
    }
    training = baselines.training_sequences(DataRecord.from_json(results["data"]))
    assert [len(t.poses) for t in training] == [len(dm.sequence_poses(n)) for n in dm.splits["train"]]
    stem = tum_test.replace("/", "_")
    entry = results["sequences"][tum_test]
    check_ape_against_evo(
        tmp_path / "run" / "trajectories", stem, entry["ape"]["trans"]["rmse"], entry["frames"]
    )


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("data.sources.tum.layout=rosbag", r"data\.sources\.tum\.layout: unknown dataset layout 'rosbag'"),
        (
            "+data.sources.tum.height=3",
            r"data\.sources\.tum\.height: unknown key \(expected some of layout",
        ),
        ("data.sources.tum.keep_every=0", r"data\.sources\.tum\.keep_every: expected an integer >= 1"),
    ],
)
def test_bad_dataset_entries_name_the_key(
    tiny_kitti: Path, tmp_path: Path, override: str, message: str
) -> None:
    from hydra.utils import instantiate

    overrides = [o for o in multi_overrides(tiny_kitti, {"tum": tmp_path}, tmp_path) if "trainer" not in o]
    cfg = compose_train([*overrides, override], tmp_path / "run")
    with pytest.raises(Exception, match=message):
        instantiate(cfg.data, _convert_="all")


@pytest.mark.slow
def test_baselines_read_other_layouts_at_the_networks_frame_rate(tmp_path: Path) -> None:
    """The report's baselines on the EuRoC layout (grey, distorted; half its native size, 40 frames): every
    2nd frame as a run with keep_every=2 saw them; ORB + E on undistorted keypoints reads the flying camera's
    rotation better than standing still, and worse when the distortion is ignored."""
    from lossvo.data import euroc
    from lossvo.evaluation import baselines
    from lossvo.evaluation.job_folder import DataRecord

    train, test = (synthetic.sequence_name("euroc", s) for s in ("00", "01"))
    root = str(
        synthetic.generate(tmp_path / "euroc", ("00", "01"), 40, layout="euroc", scale=0.5, progress=False)
    )
    data = DataRecord("lossvo.data.datamodules.VODataModule", root, [test], [], root, [train],
                      layout="euroc", train_layout="euroc", keep_every=2, train_keep_every=2)  # fmt: skip
    found = baselines.compute_baselines(data, [test], tmp_path / "cache")[test]
    frames = len(euroc.load_sequence(root, test).images)
    assert len(found[baselines.ZERO].trajectory) == (frames + 1) // 2
    orb, zero = found[baselines.ORB], found[baselines.ZERO]
    assert orb.scores.rpe.rot_rad.rmse < zero.scores.rpe.rot_rad.rmse
    seq = euroc.load_sequence(root, test).every(2)
    steps = np.linalg.norm(seq.targets[:, :3, 3], axis=1)
    ignored, _ = baselines.orb_essential(seq.images, seq.K, steps, np.eye(4))
    undistorted, _ = baselines.orb_essential(seq.images, seq.K, steps, np.eye(4), seq.distortion)

    def rotation_errors(relative: np.ndarray) -> np.ndarray:
        """(N-1,) angle (rad) between each estimated and true relative rotation."""
        R = np.swapaxes(relative[:, :3, :3], 1, 2) @ seq.targets[:, :3, :3]
        return np.arccos(np.clip((np.trace(R, axis1=1, axis2=2) - 1) / 2, -1, 1))

    assert np.median(rotation_errors(undistorted)) < np.median(rotation_errors(ignored))
