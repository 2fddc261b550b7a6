"""The one error path: which errors are the user's (one line, exit status 2) and which keep their
traceback, for argparse and Hydra entry points alike; a refused evaluation leaves no folder."""

from __future__ import annotations

import errno
import os
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from hydra.errors import InstantiationException, MissingConfigException
from lightning.fabric.utilities.exceptions import MisconfigurationException

from helpers import eval_main
from lossvo import console
from lossvo.console import UserError, one_line_main, user_message
from lossvo.evaluation import checkpoints
from lossvo.evaluation.checkpoints import CheckpointError
from lossvo.report import cli as report_cli
from lossvo.report.jobs import SweepError


def _instantiation(cause: BaseException, text: str = "Error in call to target 'x.Y':") -> BaseException:
    try:
        raise InstantiationException(f"{text}\nfull_key: model") from cause
    except InstantiationException as e:
        return e


BUGS = [TypeError("f() got an unexpected keyword"), ImportError("no module x"), AttributeError("no attr"),
        KeyError("99"), RuntimeError("bug"), ValueError("a bug's value")]  # fmt: skip


@pytest.mark.parametrize("error", BUGS)
def test_programming_errors_keep_their_traceback(error: BaseException) -> None:
    assert user_message(error) is None
    assert user_message(_instantiation(error)) is None  # raised inside a constructor


def test_user_errors_are_one_line() -> None:
    assert (
        user_message(UserError("data.root: a file\nexpected a folder"))
        == "data.root: a file; expected a folder"
    )
    assert issubclass(CheckpointError, UserError) and issubclass(SweepError, UserError)
    assert not issubclass(UserError, ValueError)  # a ValueError is a bug's, never a user error by its type
    assert user_message(MisconfigurationException("no GPU")) == "no GPU"
    assert user_message(_instantiation(UserError("bad k"))) == "model: bad k"
    located = _instantiation(ImportError("no module named nope"), "Error locating target 'nope.Net':")
    assert user_message(located) == "model._target_: cannot import 'nope.Net' (no module named nope)"
    full = OSError(errno.ENOSPC, "No space left on device", "/data/x")
    assert user_message(full) == "/data/x: No space left on device"
    assert user_message(MissingConfigException("Could not find 'loss/x'", "loss/x", ["a", "b"])) is not None


def test_an_argparse_entry_point_ends_a_user_error_in_one_line(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("LOSSVO_FULL_ERROR", raising=False)

    @one_line_main
    def refuses(argv: list[str]) -> int:
        raise UserError(f"{argv[0]}: expected a folder")

    @one_line_main
    def has_a_bug(argv: list[str]) -> int:
        raise TypeError("a bug")

    assert refuses(["--out"]) == 2
    assert capsys.readouterr().err == "error: --out: expected a folder\n"
    with pytest.raises(TypeError):
        has_a_bug([])
    monkeypatch.setenv("LOSSVO_FULL_ERROR", "1")
    with pytest.raises(UserError):
        refuses(["--out"])


def test_eval_of_a_folder_names_the_checkpoints_in_it_and_leaves_no_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.delenv("LOSSVO_FULL_ERROR", raising=False)
    job = tmp_path / "job"
    (job / "checkpoints").mkdir(parents=True)
    (job / "checkpoints" / "best.ckpt").write_bytes(b"")
    out = tmp_path / "eval"
    status, err = eval_main([f"ckpt_path={job}", f"hydra.run.dir={out}"], monkeypatch, capsys)
    assert status == 2
    assert (
        err.strip()
        == f"error: ckpt_path: {job} is a folder, expected a .ckpt file (in it: checkpoints/best.ckpt)"
    )
    assert not out.exists()  # neither .hydra/ nor an empty eval.log


def test_a_refused_eval_keeps_a_folder_that_held_something(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "eval"
    out.mkdir()
    (out / "notes.txt").write_text("mine\n")
    status, err = eval_main(
        [f"ckpt_path={tmp_path / 'missing.ckpt'}", f"hydra.run.dir={out}"], monkeypatch, capsys
    )
    assert status == 2 and err.startswith("error: ") and len(err.strip().splitlines()) == 1
    assert (out / "notes.txt").is_file()


def test_a_config_key_the_target_lacks_is_the_users_a_type_error_inside_it_is_not() -> None:
    unknown = TypeError("Trainer.__init__() got an unexpected keyword argument 'foo'")
    text = "Error in call to target 'lightning.pytorch.trainer.trainer.Trainer':"
    assert (
        user_message(_instantiation(unknown, text))
        == "model: Trainer.__init__() got an unexpected keyword argument 'foo'"
    )
    inside = TypeError("helper() got an unexpected keyword argument 'foo'")  # a call inside the constructor
    assert user_message(_instantiation(inside, text)) is None


@contextmanager
def read_only(folder: Path) -> Iterator[None]:
    """``folder`` read-only while the block runs: by its mode for a user, by a read-only bind mount for
    root (who writes into any mode); skips the test where neither can be had."""
    if os.geteuid() != 0:
        folder.chmod(0o555)
        try:
            yield
        finally:
            folder.chmod(0o755)
        return
    mount = ["mount", "--bind", str(folder), str(folder)]
    if subprocess.run(mount, capture_output=True).returncode != 0:
        pytest.skip("root, and no read-only bind mount here")
    try:
        remount = ["mount", "-o", "remount,ro,bind", str(folder)]
        if subprocess.run(remount, capture_output=True).returncode != 0:
            pytest.skip("root, and no read-only bind mount here")
        yield
    finally:
        subprocess.run(["umount", str(folder)], capture_output=True)


def test_the_report_of_a_read_only_sweep_suggests_out(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sweep = tmp_path / "sweep"
    (sweep / "0_loss-euler" / ".hydra").mkdir(parents=True)
    (sweep / "0_loss-euler" / ".hydra" / "config.yaml").write_text("seed: 0\n")
    with read_only(sweep):
        status = report_cli.main([str(sweep)])
    assert status == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {sweep / 'report'}: cannot write the report there (")
    assert err.endswith("): write the report elsewhere with --out DIR\n") and err.count("\n") == 1


@pytest.mark.parametrize("text", ["not a checkpoint\n", "epoch 3\n"])
def test_a_text_file_as_a_checkpoint_is_named_as_such(tmp_path: Path, text: str) -> None:
    """Whatever the text (pickle reads ``e`` as opcode 101: ``KeyError: 101``), one message."""
    path = tmp_path / "best.ckpt"
    path.write_text(text)
    with pytest.raises(CheckpointError) as error:
        checkpoints.read(path)
    assert (
        str(error.value) == f"{path}: cannot load as a lossvo checkpoint (not a file written by torch.save)"
    )


def test_the_hydra_flags_are_those_of_hydras_parser() -> None:
    """console.HYDRA_FLAGS is written out (no private import in the product); Hydra's parser is its
    reference here, so a Hydra release that adds or drops a flag fails this test."""
    from hydra._internal.utils import get_args_parser

    parser = get_args_parser()
    assert {option for action in parser._actions for option in action.option_strings} == console.HYDRA_FLAGS


PATCHED_TRAIN = """
import runpy, sys
from lossvo.console import UserError
from lossvo.training import fitting

def build(cfg):
    raise {error}

fitting.build = build  # deep in training: after the config is composed and the run folder accepted
sys.argv = ["lossvo.train", *sys.argv[1:]]
runpy.run_module("lossvo.train", run_name="__main__", alter_sys=True)
"""
"""``python -m lossvo.train`` with ``fitting.build`` replaced by one that raises ``{error}``."""


@pytest.mark.slow
@pytest.mark.parametrize(
    ("error", "status", "one_line"),
    [
        ('UserError("data.root: /x is a file, expected a folder")', 2, True),
        ('ValueError("a bug deep in training")', 1, False),
    ],
)
def test_train_ends_a_user_error_in_one_line_and_a_bug_in_its_traceback(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, error: str, status: int, one_line: bool
) -> None:
    for name in ("LOSSVO_FULL_ERROR", "HYDRA_FULL_ERROR"):
        monkeypatch.delenv(name, raising=False)
    script = tmp_path / "train.py"
    script.write_text(PATCHED_TRAIN.format(error=error))
    done = subprocess.run([sys.executable, str(script), f"hydra.run.dir={tmp_path / 'run'}"],
                          capture_output=True, text=True, timeout=300)  # fmt: skip
    message = error.split("(", 1)[1].rstrip(")").strip('"')
    output = done.stdout + done.stderr
    assert done.returncode == status, output
    if one_line:  # logged once (the job's log is on the terminal), no traceback
        lines = [line for line in output.splitlines() if message in line]
        assert "Traceback" not in output and len(lines) == 1 and lines[0].endswith(message), output
    else:
        assert "Traceback (most recent call last)" in done.stderr, output
        assert done.stderr.rstrip().endswith(f"{error.split('(')[0]}: {message}"), output
