"""Every row of docs/bad-input.md: the command, given the bad input, exits with the status in the table
and prints exactly one line of error output, which contains the row's message, and no traceback.

Rows run in process (a subprocess spends seconds importing torch); the first row of train (a Hydra main)
and of the synthetic generator (an argparse command) also as the real command line.
``LOSSVO_FULL_ERROR=1`` gives the traceback instead.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest
import torch

from helpers import exit_status, fit, run_hydra_main, train_main
from lossvo import eval as lossvo_eval
from lossvo import metrics as metrics_cli
from lossvo.console import UserError
from lossvo.data.synthetic import cli as synthetic_cli
from lossvo.report import cli as report_cli
from lossvo.training import shared_study
from test_train import compose_train, tiny_overrides

DOC = Path(__file__).resolve().parents[1] / "docs" / "bad-input.md"
COMMANDS = {
    "python -m lossvo.train": "train",
    "python -m lossvo.eval": "eval",
    "python -m lossvo.report": "report",
    "python -m lossvo.metrics": "metrics",
    "python -m lossvo.data.synthetic": "synthetic",
}
REAL = ("train", "synthetic")
"""Commands whose first row also runs as a subprocess."""


@dataclass(frozen=True)
class Row:
    command: str
    input: str
    found: str
    message: str
    status: int

    @property
    def id(self) -> str:
        return f"{self.command}:{self.input}"


def _code(cell: str) -> str:
    match = re.fullmatch(r"`([^`]*)`", cell)
    assert match, f"expected one `code` span, got {cell!r}"
    return match.group(1)


def read_table(path: Path) -> list[Row]:
    """The rows of the bad-input table (lines starting ``| `python -m``)."""
    rows = []
    for line in path.read_text().splitlines():
        if line.startswith("| `python -m "):
            cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
            assert len(cells) == 5, line
            command, bad, found, message, status = cells
            rows.append(Row(COMMANDS[_code(command)], _code(bad), found, _code(message), int(status)))
    return rows


ROWS = read_table(DOC)


def test_the_table_covers_every_command() -> None:
    assert len(ROWS) >= 20 and {row.command for row in ROWS} == set(COMMANDS.values())
    assert len({row.id for row in ROWS}) == len(ROWS)


# -- the placeholders of the table -----------------------------------------------------------------


@pytest.fixture(scope="module")
def euler_checkpoint(tiny_kitti: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A checkpoint of one tiny training step with loss=euler, data.windows.seq_len=3."""
    base = tmp_path_factory.mktemp("euler")
    overrides = [*tiny_overrides(tiny_kitti, base / "cache"), "loss=euler", "trainer.max_epochs=1",
                 "+evaluate=false", "+trainer.limit_train_batches=1", "+trainer.limit_val_batches=1",
                 "callbacks.trajectory_validation=null"]  # fmt: skip
    fit(compose_train(overrides, base / "run"))
    return base / "run" / "checkpoints" / "best.ckpt"


@pytest.fixture(scope="module")
def other_study(tmp_path_factory: pytest.TempPathFactory) -> str:
    """The URL of an SQLite storage holding the study ``k_search`` created for another search (maximising)."""
    url = f"sqlite:///{tmp_path_factory.mktemp('other_study') / 'optuna.db'}"
    shared_study.check_study(url, "k_search", {"directions": ["maximize"], "space": {}, "fixed": {}})
    return url


@pytest.fixture
def places(tiny_kitti: Path, euler_checkpoint: Path, other_study: str, tmp_path: Path) -> dict[str, str]:
    """The table's placeholders -> paths (files made afresh for each row)."""
    poses = (tiny_kitti / "poses" / "00.txt").read_text().splitlines()
    assert len(poses) == 10
    files = {
        "<poses>": poses,
        "<shorter poses>": poses[:4],
        "<malformed poses>": [*poses[:2], "1 2 3", *poses[3:]],
    }
    for name, lines in files.items():
        (tmp_path / name.strip("<>").replace(" ", "_")).write_text("\n".join(lines) + "\n")
    (tmp_path / "text_file").write_text("not a checkpoint\n")
    (tmp_path / "empty_folder").mkdir()
    (tmp_path / "job_without_config" / "0_loss-euler").mkdir(parents=True)
    (tmp_path / "one_job_sweep" / "0_loss-euler" / ".hydra").mkdir(parents=True)
    (tmp_path / "one_job_sweep" / "0_loss-euler" / ".hydra" / "config.yaml").write_text("seed: 0\n")
    torch.save({"hyper_parameters": {"model": {}, "loss": {}}, "state_dict": {}, "schema_version": 3},
               tmp_path / "newer_checkpoint")  # fmt: skip
    (tmp_path / "newer_run").mkdir()
    (tmp_path / "newer_run" / "status.json").write_text('{"schema_version": 2, "status": "completed"}\n')
    names = ["<poses>", "<shorter poses>", "<malformed poses>", "<text file>", "<empty folder>",
             "<job without config>", "<one job sweep>", "<missing file>", "<missing folder>",
             "<new folder>", "<newer checkpoint>", "<newer run>"]  # fmt: skip
    paths = {name: str(tmp_path / name.strip("<>").replace(" ", "_")) for name in names}
    return {**paths, "<tiny KITTI>": str(tiny_kitti), "<euler checkpoint>": str(euler_checkpoint),
            "<study of another search>": other_study}  # fmt: skip


def fill(text: str, places: dict[str, str]) -> str:
    for name, value in places.items():
        text = text.replace(name, value)
    assert not re.search(r"<(?!time>|num>|overrides>)[a-zA-Z ]+>", text), f"unknown placeholder in {text!r}"
    return text


# -- running a row ---------------------------------------------------------------------------------


def train_argv(args: list[str], tiny_kitti: Path, tmp_path: Path) -> list[str]:
    """The training command line of a row: the working one with the row's input added (without its
    network's settings where the row chooses ``model=``), or the row's input alone where it chooses
    ``data=``."""
    chooses_data = any(arg.startswith("data=") for arg in args)
    base = [] if chooses_data else tiny_overrides(tiny_kitti, tmp_path / "cache")
    if any(arg.startswith("model=") for arg in args):  # the tiny DeepVO's settings are not another network's
        base = [arg for arg in base if not arg.startswith("model.")]
    return [f"hydra.run.dir={tmp_path / 'run'}", *base, *args]


def run_row(
    row: Row, args: list[str], tiny_kitti: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> int:
    """Run a row in process; its exit status."""
    if row.command == "train":
        return train_main(train_argv(args, tiny_kitti, tmp_path), monkeypatch)
    if row.command == "eval":
        argv = ["lossvo.eval", f"hydra.run.dir={tmp_path / 'run'}", *args]
        return run_hydra_main(lossvo_eval.main, argv, monkeypatch)
    mains = {"report": report_cli.main, "metrics": metrics_cli.main, "synthetic": synthetic_cli.main}
    main = mains[row.command]
    try:
        return int(main(args))
    except SystemExit as e:
        return exit_status(e)


LOG_RECORD = re.compile(r"\[[^]]*\]\[[^]]*\]\[(?:DEBUG|INFO|WARNING)\] - ")


def error_lines(output: str) -> list[str]:
    """The lines of output that are not log records below ERROR, as a terminal shows them (a progress
    bar redrawn with carriage returns leaves what it last drew)."""
    shown = re.sub(r"[^\n]*\r(?!\n)", "", output)
    return [line for line in shown.splitlines() if line.strip() and not LOG_RECORD.match(line)]


def check_output(row: Row, message: str, status: int, out: str, err: str) -> None:
    assert status == row.status, f"exit status {status}, expected {row.status}:\n{out}\n{err}"
    assert "Traceback" not in out + err
    lines = error_lines(out + "\n" + err)
    assert len(lines) == 1, f"expected one line of error output, got {len(lines)}:\n" + "\n".join(lines)
    assert message in lines[0], f"{message!r} not in {lines[0]!r}"
    assert lines[0] in err.splitlines() and not error_lines(out), out  # the line is on stderr
    if row.command in ("report", "metrics", "synthetic"):
        assert not out.strip(), out  # nothing on stdout


def check_nothing_done(row: Row, places: dict[str, str], tmp_path: Path) -> None:
    """What a row's failure leaves: a training job's status, no report, no dataset."""
    run = tmp_path / "run"
    if row.command in ("train", "eval"):
        assert not run.exists()  # a run or an evaluation refused before it starts leaves no folder
    assert not Path(places["<new folder>"]).exists()
    for folder in ("<empty folder>", "<job without config>"):
        assert not (Path(places[folder]) / "report").exists()


@pytest.mark.slow
@pytest.mark.parametrize("row", ROWS, ids=[row.id for row in ROWS])
def test_row(row: Row, places: dict[str, str], tiny_kitti: Path, tmp_path: Path,
             monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    monkeypatch.setenv("LOSSVO_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv("LOSSVO_FULL_ERROR", raising=False)
    status = run_row(row, shlex.split(fill(row.input, places)), tiny_kitti, tmp_path, monkeypatch)
    captured = capsys.readouterr()
    check_output(row, fill(row.message, places), status, captured.out, captured.err)
    check_nothing_done(row, places, tmp_path)


# -- the real command lines ------------------------------------------------------------------------

FIRST = {command: next(row for row in ROWS if row.command == command) for command in REAL}


@pytest.fixture(scope="module")
def real_runs(tiny_kitti: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple]:
    """The first row of each REAL command as ``python -m ...``, the processes started together:
    command -> (row, message, exit status, stdout, stderr)."""
    tmp = tmp_path_factory.mktemp("real")
    env = {**os.environ, "LOSSVO_CACHE": str(tmp / "cache")}
    env.pop("LOSSVO_FULL_ERROR", None)
    modules = {command: module.split()[-1] for module, command in COMMANDS.items()}
    procs = {}
    for command, row in FIRST.items():
        folder = tmp / command
        folder.mkdir()
        places = {"<new folder>": str(folder / "new"), "<missing folder>": str(folder / "missing"),
                  "<tiny KITTI>": str(tiny_kitti)}  # fmt: skip
        args = shlex.split(fill(row.input, places))
        if command == "train":
            args = train_argv(args, tiny_kitti, folder)
        procs[command] = (row, fill(row.message, places), subprocess.Popen(
            [sys.executable, "-m", modules[command], *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            text=True, env=env, cwd=folder))  # fmt: skip
    done = {}
    for command, (row, message, proc) in procs.items():
        out, err = proc.communicate(timeout=300)
        done[command] = (row, message, proc.returncode, out, err)
    return done


@pytest.mark.slow
@pytest.mark.parametrize("command", REAL)
def test_the_real_command_line(real_runs: dict[str, tuple], command: str) -> None:
    row, message, status, out, err = real_runs[command]
    check_output(row, message, status, out, err)
    if command == "train":  # found before anything: the only line printed at all
        assert len((out + err).strip().splitlines()) == 1, out + err


# -- a GPU trainer where there is no GPU ------------------------------------------------------------

NO_GPU = Row("train", "trainer=gpu", "before anything is built", "trainer=gpu: no CUDA GPU here "
             "(torch.cuda.is_available() is false): use trainer=default to train on the CPU", 2)  # fmt: skip
"""``trainer=gpu`` on a machine without a CUDA GPU (where there is one, the command trains)."""

needs_no_gpu = pytest.mark.skipif(torch.cuda.is_available(), reason="a CUDA GPU is here: trainer=gpu trains")


@needs_no_gpu
def test_trainer_gpu_without_a_gpu_names_trainer_default(
    tiny_kitti: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """In process: the config check's line (logged as the run's error), exit status 2, no run folder."""
    monkeypatch.setenv("LOSSVO_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv("LOSSVO_FULL_ERROR", raising=False)
    status = run_row(NO_GPU, ["trainer=gpu"], tiny_kitti, tmp_path, monkeypatch)
    captured = capsys.readouterr()
    check_output(NO_GPU, NO_GPU.message, status, captured.out, captured.err)
    assert not (tmp_path / "run").exists()


@pytest.mark.slow
@needs_no_gpu
def test_trainer_gpu_without_a_gpu_on_the_real_command_line(tiny_kitti: Path, tmp_path: Path) -> None:
    """``python -m lossvo.train trainer=gpu`` (the tiny data's command line): one line in all, exit status 2,
    before Lightning is asked for the GPU (its own line says "No supported gpu backend found")."""
    env = {**os.environ, "LOSSVO_CACHE": str(tmp_path / "cache")}
    env.pop("LOSSVO_FULL_ERROR", None)
    argv = [sys.executable, "-m", "lossvo.train", *train_argv(["trainer=gpu"], tiny_kitti, tmp_path)]
    done = subprocess.run(argv, capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300)
    check_output(NO_GPU, NO_GPU.message, done.returncode, done.stdout, done.stderr)
    assert len((done.stdout + done.stderr).strip().splitlines()) == 1, done.stdout + done.stderr
    assert not (tmp_path / "run").exists()


# -- LOSSVO_FULL_ERROR -----------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize(
    ("command", "args", "error"),
    [
        ("train", "data.windows.batch_size=0", UserError),
        ("train", "data.windows.batch_size=abc", Exception),  # Hydra's ConfigCompositionException
        ("train", "loss=eular", Exception),  # Hydra's MissingConfigException
        ("eval", "device=cpu", UserError),
        ("report", "<missing folder>", UserError),
        ("metrics", "<poses> <malformed poses>", UserError),
        ("synthetic", "--out <new folder> --frames 1", UserError),
    ],
)
def test_full_error_shows_the_traceback(command: str, args: str, error: type[Exception],
                                        places: dict[str, str], tiny_kitti: Path, tmp_path: Path,
                                        monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    """With LOSSVO_FULL_ERROR=1 the error is raised, not reported: the interpreter prints its traceback."""
    monkeypatch.setenv("LOSSVO_FULL_ERROR", "1")
    monkeypatch.delenv("HYDRA_FULL_ERROR", raising=False)
    monkeypatch.setenv("LOSSVO_CACHE", str(tmp_path / "cache"))
    row = Row(command, args, "", "", 1)
    with pytest.raises(error) as raised:
        run_row(row, shlex.split(fill(args, places)), tiny_kitti, tmp_path, monkeypatch)
    assert raised.traceback and "HYDRA_FULL_ERROR" not in os.environ
