"""Faults a run must survive. Each ends in a resumable run or a one-line error, never in lost work or in a run
counted finished; the tests check the run folder afterwards and then finish the run with the command the
error printed.

The file is one section per kind of fault; a new case goes in its section (a new kind, in a section of its own):

- damaged checkpoints: truncated and zeroed model zip, replay buffer pickle and ``checkpoint.json``;
- disk full: a write that fails with ENOSPC, in a checkpoint and in the final save;
- signals: SIGINT and SIGKILL of ``sgfd-zoo train`` subprocesses, at chosen and at random points;
- partial final models: what a stopped run's folder may hold is never taken for a finished run;
- configuration typos: unknown keys inside the kwargs hyperparameters, in every command that reads them.

- bad data: a NaN reward, an out-of-range domain label from an env, refused before the replay buffer stores it.

Every run is the quick configuration of SAC on states, cut to a few hundred steps with a tiny network.
"""

from __future__ import annotations

import errno
import functools
import json
import os
import random
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy
import pytest
import ray
import stable_baselines3.common.base_class
import stable_baselines3.common.off_policy_algorithm
from stable_baselines3.common.save_util import load_from_pkl

import sgfd_envs.dmc
from sgfd_cli import main as zoo_main
from sgfd_zoo import training
from sgfd_zoo.runs.checkpoints import read_index, remove_checkpoint_files
from sgfd_zoo.runs.folders import FINISHED_MARKER, RunFolder
from sgfd_zoo.runs.locks import LOCK_FILE, RunLock
from sgfd_zoo.sweep import command as sweep
from tests.zoo.zoo_runs import ENV_ID, NAME, SETTINGS, TINY_PARAMS, Training, has_checkpoint, train_args, zoo


def printed_command(line: str, after: str) -> list[str]:
    """The ``sgfd-zoo`` arguments of the command a message gives after ``after``."""
    command = shlex.split(line.split(after, 1)[1])
    assert command[0] == "sgfd-zoo", line
    return command[1:]


def leftovers(run: Path) -> list[str]:
    """Files the run should not have: what an interrupted write left, checkpoint files its index does not list."""
    listed = {stored.name for checkpoint in read_index(run) for stored in checkpoint.files.values()}
    names = [path.name for path in run.rglob("*") if path.is_file()]
    return sorted(n for n in names if n.startswith(".tmp-") or (n.startswith("checkpoint_") and n not in listed))


def assert_finished(run: Path, steps: int) -> None:
    folder = RunFolder(run)
    assert folder.finished and leftovers(run) == []
    assert folder.load_model().num_timesteps == steps


@pytest.fixture(scope="module")
def stopped_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A run with checkpoints at 200 and 400 steps and no final model: the state a kill during the final save
    leaves (trained to the end, then the final model and its marker taken away)."""
    folder = tmp_path_factory.mktemp("faults") / "logs"
    code, _out, err = zoo(train_args(folder))
    assert code == 0, err
    run = folder / "sac" / f"{NAME}_1"
    (run / f"{NAME}.zip").unlink()
    (run / FINISHED_MARKER).unlink()
    assert not RunFolder(run).finished
    assert [checkpoint.num_timesteps for checkpoint in read_index(run)] == [400, 200]
    return folder


@pytest.fixture
def logs(stopped_run: Path, tmp_path: Path) -> Path:
    """A copy of ``stopped_run``'s log folder for one test to damage."""
    return Path(shutil.copytree(stopped_run, tmp_path / "logs"))


def run_of(logs: Path) -> Path:
    return logs / "sac" / f"{NAME}_1"


def truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def zero(path: Path) -> None:
    path.write_bytes(bytes(path.stat().st_size))


# -- damaged checkpoints --------------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("damage", [truncate, zero], ids=["truncated", "zeroed"])
@pytest.mark.parametrize("part", ["model", "replay_buffer"])
def test_a_damaged_newest_checkpoint_resumes_from_the_previous_one(logs: Path, part: str, damage: Callable) -> None:
    run = run_of(logs)
    damaged = read_index(run)[0].files[part].name
    damage(run / damaged)

    code, out, err = zoo(train_args(logs, "--resume"))

    assert code == 0, err
    warnings = [line for line in err if line.startswith("warning: ")]
    assert len(warnings) == 1 and damaged in warnings[0]
    assert warnings[0].endswith("resuming from the checkpoint at 200 steps")
    assert f"Resuming {run} from 200 steps" in out
    assert_finished(run, 400)
    assert [checkpoint.num_timesteps for checkpoint in read_index(run)] == [400, 200]
    assert read_index(run)[0].problem(run) is None  # the damaged file was written again


@pytest.mark.parametrize("damage", [truncate, zero], ids=["truncated", "zeroed"])
def test_a_damaged_index_resumes_from_the_checkpoint_files(logs: Path, damage: Callable) -> None:
    run = run_of(logs)
    damage(run / "checkpoint.json")

    code, out, err = zoo(train_args(logs, "--resume"))

    # The files of the 400-step checkpoint are whole: nothing to train, the final model is saved from them.
    assert code == 0, err
    warnings = [line for line in err if line.startswith("warning: ")]
    assert len(warnings) == 1 and "checkpoint.json is unreadable" in warnings[0]
    assert f"Resuming {run} from 400 steps" in out
    assert_finished(run, 400)
    assert [checkpoint.num_timesteps for checkpoint in read_index(run)] == [400, 200]
    assert all(stored.sha256 for stored in read_index(run)[0].files.values())  # the index is whole again


@pytest.mark.slow
def test_with_no_usable_checkpoint_one_line_names_the_file_and_the_command_that_restarts_the_run(logs: Path) -> None:
    run = run_of(logs)
    newest, previous = read_index(run)
    zero(run / newest.files["model"].name)
    truncate(run / previous.files["replay_buffer"].name)

    code, out, err = zoo(train_args(logs, "--resume"))

    assert code == 2 and len(err) == 1, err
    assert err[0].startswith(f"sgfd-zoo train: error: --resume: no usable checkpoint in {run}: ")
    assert newest.files["model"].name in err[0] and previous.files["replay_buffer"].name in err[0]
    assert not RunFolder(run).finished
    restart = printed_command(err[0], "start the run again with: ")
    assert "--resume" not in restart and restart[-2:] == ["--run-id", "1"]
    # The command starts it again in its folder, from step 0; the unusable files go.
    code, out, err = zoo(restart)
    assert code == 0, err
    assert any(line.startswith(f"Starting {run} again from step 0") for line in err) and "Resuming" not in out
    assert_finished(run, 400)


def test_an_index_from_before_checksums_still_resumes(logs: Path) -> None:
    run = run_of(logs)
    newest = read_index(run)[0]
    index = {"num_timesteps": 400, **{part: stored.name for part, stored in newest.files.items()}}
    (run / "checkpoint.json").write_text(json.dumps(index))  # file names only, no sizes or checksums

    code, out, err = zoo(train_args(logs, "--resume"))

    assert code == 0, err
    assert f"Resuming {run} from 400 steps" in out and not [line for line in err if line.startswith("warning")]
    assert_finished(run, 400)


def test_a_broken_folder_does_not_stop_a_sweep_from_planning(logs: Path, capsys: pytest.CaptureFixture) -> None:
    run = run_of(logs)
    zero(run / "checkpoint.json")
    (run / NAME / "config.yml").write_text("n_timesteps: [")
    # A typo stops the sweep at its pre-check, after planning and before Ray starts.
    argv = ["sweep", "--algos", "sac", "--envs", ENV_ID, "--seeds", "0", "-f", str(logs), *SETTINGS[:1]]
    argv += ["-params", "policy_kwargs:dict(net_archh=[32])"]
    assert zoo_main(argv) == 2
    captured = capsys.readouterr()
    # Planning reported both unreadable files, counted the run as one to resume, and went on to the pre-check.
    assert f"sweep: {run / 'checkpoint.json'} is unreadable (" in captured.out
    assert f"sweep: {run / NAME / 'config.yml'} is unreadable (" in captured.out
    assert "1 to train (1 to resume)" in captured.out
    assert "net_archh" in captured.err.strip().splitlines()[-1] and not ray.is_initialized()


# -- disk full ------------------------------------------------------------------------------------------------


def failing_on(call: int, real: Callable, write_first: int = 1000) -> Callable:
    """``real``, except that its ``call``-th call writes a few bytes and fails as a full disk does."""
    calls = []

    @functools.wraps(real)
    def write(path, *args, **kwargs):
        calls.append(path)
        if len(calls) != call:
            return real(path, *args, **kwargs)
        with open(path, "wb") as handle:
            handle.write(b"\0" * write_first)
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    return write


@pytest.mark.slow
def test_a_full_disk_during_a_checkpoint_stops_training_in_one_line_and_keeps_the_previous_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    real = stable_baselines3.common.off_policy_algorithm.save_to_pkl
    monkeypatch.setattr(stable_baselines3.common.off_policy_algorithm, "save_to_pkl", failing_on(2, real))
    logs = tmp_path / "logs"

    code, out, err = zoo(train_args(logs, steps=600))

    run = run_of(logs)
    assert code == 1 and err[-1].startswith("sgfd-zoo train: stopped: the checkpoint at 400 steps was not written to ")
    room = r"\(it needs about [\d.]+ [kMG]B, [\d.]+ [kMG]B free\)"
    assert re.search(f"written to {re.escape(str(run))}: No space left on device {room}; ", err[-1]), err[-1]
    assert "the previous checkpoint (200 steps) is intact; free space, then continue it with: " in err[-1]
    assert not [line for line in err if "Traceback" in line]
    assert [checkpoint.num_timesteps for checkpoint in read_index(run)] == [200]
    assert read_index(run)[0].problem(run) is None and leftovers(run) == []
    assert not RunFolder(run).finished and not (run / f"{NAME}.zip").exists()

    monkeypatch.setattr(stable_baselines3.common.off_policy_algorithm, "save_to_pkl", real)  # space freed
    code, out, err = zoo(printed_command(err[-1], "continue it with: "))
    assert code == 0, err
    assert f"Resuming {run} from 200 steps" in out
    assert_finished(run, 600)


@pytest.mark.slow
def test_a_full_disk_before_any_checkpoint_stops_training_and_names_the_command_that_starts_it_again(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(numpy, "savez", failing_on(1, numpy.savez))  # the first evaluation's file
    logs = tmp_path / "logs"
    run = run_of(logs)

    code, _out, err = zoo([*train_args(logs, steps=200), "--eval-freq", "100", "--eval-episodes", "1"])

    assert code == 1 and err[-1].startswith("sgfd-zoo train: stopped: evaluations_train.npz (at 100 steps) was not ")
    assert f"written to {run}: No space left on device (it needs more than 1 kB, " in err[-1]
    assert f"no checkpoint in {run}; free space, then start it again with: " in err[-1]
    assert not RunFolder(run).finished and leftovers(run) == [] and not list(run.glob("evaluations_*"))
    monkeypatch.setattr(numpy, "savez", numpy.savez.__wrapped__)
    code, _out, err = zoo(printed_command(err[-1], "start it again with: "))
    assert code == 0, err
    assert_finished(run, 200)


def test_a_full_disk_during_the_final_save_leaves_the_run_unfinished_and_resumable(
    logs: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    real = stable_baselines3.common.base_class.save_to_zip_file
    monkeypatch.setattr(stable_baselines3.common.base_class, "save_to_zip_file", failing_on(1, real))
    run = run_of(logs)

    code, _out, err = zoo(train_args(logs, "--resume"))  # nothing to train: the final save only

    assert code == 1 and err[-1].startswith(f"sgfd-zoo train: stopped: the final model was not written to {run}: ")
    assert re.search(r"No space left on device \(it needs about \d+ kB, ", err[-1]), err[-1]  # the model's size
    assert "the run is not finished; free space, then continue it with: " in err[-1]
    assert not RunFolder(run).finished and leftovers(run) == []
    monkeypatch.setattr(stable_baselines3.common.base_class, "save_to_zip_file", real)
    code, _out, err = zoo(printed_command(err[-1], "continue it with: "))
    assert code == 0, err
    assert_finished(run, 400)


# -- signals --------------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_ctrl_c_stops_a_fresh_and_a_resumed_run_at_a_checkpoint(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    run = run_of(logs)
    fresh = Training(train_args(logs, steps=600), tmp_path / "fresh")
    fresh.wait_until(has_checkpoint(run))

    assert fresh.send(signal.SIGINT) == 130
    line = fresh.last_error()
    stopped = read_index(run)[0].num_timesteps
    assert line.startswith(f"sgfd-zoo train: stopped: Ctrl-C at {stopped} steps: its checkpoint at {stopped} steps")
    assert "the run is not finished; continue it with: " in line
    assert read_index(run)[0].problem(run) is None and leftovers(run) == []
    assert not RunFolder(run).finished and not (run / f"{NAME}.zip").exists()

    resumed = Training(printed_command(line, "continue it with: "), tmp_path / "resumed")
    resumed.wait_until(lambda: read_index(run)[0].num_timesteps > stopped)  # training again, past a checkpoint
    assert resumed.send(signal.SIGINT) == 130
    line = resumed.last_error()
    again = read_index(run)[0].num_timesteps
    assert again > stopped and line.startswith(f"sgfd-zoo train: stopped: Ctrl-C at {again} steps: ")
    assert f"Resuming {run} from {stopped} steps" in resumed.out.read_text()
    assert not RunFolder(run).finished and leftovers(run) == []

    code, out, err = zoo(printed_command(line, "continue it with: "))
    assert code == 0, err
    assert f"Resuming {run} from {again} steps" in out
    assert_finished(run, 600)


# A big replay buffer (200k transitions: ~50 MB to write) holds each save open long enough to signal inside it.
BIG_BUFFER = ["-params", *TINY_PARAMS, "buffer_size:200000"]


@pytest.mark.slow
@pytest.mark.parametrize(
    ("signum", "times", "writing"),
    [
        (signal.SIGKILL, 1, "checkpoint_replay_buffer_400_steps.pkl"),
        (signal.SIGINT, 1, "checkpoint_replay_buffer_400_steps.pkl"),
        (signal.SIGINT, 2, "checkpoint_replay_buffer_400_steps.pkl"),
        (signal.SIGKILL, 1, "replay_buffer.pkl"),  # the final save (--save-replay-buffer: the buffer first)
        (signal.SIGINT, 1, "replay_buffer.pkl"),
    ],
    ids=["kill-in-checkpoint", "ctrl-c-in-checkpoint", "ctrl-c-twice", "kill-in-final-save", "ctrl-c-in-final-save"],
)
def test_a_signal_during_a_save(tmp_path: Path, signum: int, times: int, writing: str) -> None:
    logs = tmp_path / "logs"
    run = run_of(logs)
    steps = 600 if "checkpoint" in writing else 400
    args = [*train_args(logs, "--save-replay-buffer", steps=steps), *BIG_BUFFER]
    training_run = Training(args, tmp_path / "first")
    # the temporary file of that write (its name is the file's, after a prefix unique to the writing process)
    training_run.wait_until(lambda: any(run.glob(f".tmp-*-{writing}")))

    code = training_run.send(signum, times)

    newest = read_index(run)[0]
    assert newest.problem(run) is None
    if times == 2:
        # The second stops at once: the checkpoint being written is removed and the one before kept (or, where
        # the write was done before the second came, it is kept: a machine decides).
        assert code == 130 and newest.num_timesteps in (200, 400) and leftovers(run) == []
        assert training_run.last_error().startswith("sgfd-zoo train: ")
    elif signum == signal.SIGINT and "checkpoint" in writing:
        # The checkpoint being written is finished, and training stops at it.
        assert code == 130 and newest.num_timesteps == 400
        assert training_run.last_error().startswith("sgfd-zoo train: stopped: Ctrl-C at 400 steps: ")
    elif signum == signal.SIGINT:
        # The final save is finished: the run ended.
        assert code == 0, training_run.err.read_text()[-3000:]
        assert_finished(run, 400)
        return
    else:
        assert code == -signal.SIGKILL
        assert newest.num_timesteps == (200 if "checkpoint" in writing else 400)
    assert not RunFolder(run).finished
    code, out, err = zoo([*train_args(logs, "--resume", steps=steps), *BIG_BUFFER])
    assert code == 0, err
    assert f"Resuming {run} from {newest.num_timesteps} steps" in out
    assert_finished(run, steps)


@pytest.mark.slow
def test_signals_at_random_points_leave_a_finished_or_a_resumable_run(tmp_path: Path) -> None:
    seed = random.randrange(10**6)
    draw = random.Random(seed)
    for trial in range(2):
        logs = tmp_path / f"trial{trial}"
        run = run_of(logs)
        signum = draw.choice([signal.SIGINT, signal.SIGKILL])
        delay = draw.uniform(1.0, 20.0)  # imports and setup take ~10 s, the 400 steps a few more
        where = f"seed {seed}, trial {trial}: {signal.Signals(signum).name} after {delay:.1f} s"
        training_run = Training(train_args(logs), tmp_path / f"process{trial}")
        time.sleep(delay)
        code = training_run.send(signum) if training_run.process.poll() is None else training_run.process.returncode
        folder = RunFolder(run)
        if folder.finished:  # ended before the signal, or the signal came after the final save (while exiting)
            assert_finished(run, 400)
            continue
        assert code in (130, -signal.SIGINT, -signal.SIGKILL), where
        if signum == signal.SIGINT and code == 130:
            assert training_run.last_error().startswith(("sgfd-zoo train: stopped: Ctrl-C", "sgfd-zoo train: inter"))
        checkpoint, problems = folder.usable_checkpoint()
        assert problems == [], where
        resume = ["--resume"] if checkpoint is not None else (["--run-id", "1"] if run.exists() else [])
        code, _out, err = zoo(train_args(logs, *resume))
        assert code == 0, f"{where}: {err}"
        assert_finished(run, 400)


KILLED_TAKING_THE_LOCK = """
import os, signal, sys
from pathlib import Path
from sgfd_zoo.runs.locks import RunLock
os.link = lambda *_: os.kill(os.getpid(), signal.SIGKILL)  # killed between writing its lock file and linking it
RunLock.acquire(Path(sys.argv[1]))
"""


def test_a_lock_file_left_by_a_process_killed_taking_the_lock_is_seen_and_removed_by_the_writer(
    tmp_path: Path,
) -> None:
    run = tmp_path / "run"
    run.mkdir()
    killed = subprocess.run([sys.executable, "-c", KILLED_TAKING_THE_LOCK, str(run)], capture_output=True, timeout=120)
    assert killed.returncode == -signal.SIGKILL, killed.stderr.decode()[-2000:]
    left = leftovers(run)
    assert len(left) == 1 and left[0].endswith(f"-{LOCK_FILE}"), sorted(path.name for path in run.iterdir())

    lock = RunLock.acquire(run)  # the next writer; its checkpoints remove what interrupted writes left
    try:
        assert remove_checkpoint_files(run, []) == left and leftovers(run) == []
    finally:
        lock.release()
    assert list(run.iterdir()) == []


# -- partial final models ------------------------------------------------------------------------------------


@pytest.mark.parametrize("final_model", ["short of its total", "cut short"])
def test_a_partial_final_model_is_never_taken_for_a_finished_run(logs: Path, final_model: str) -> None:
    run = run_of(logs)
    newest, previous = read_index(run)
    # What rl-zoo3 left before the zoo's marker existed: the model of a run stopped by Ctrl-C, saved as final;
    # or the file a kill during its final save left.
    if final_model == "short of its total":
        shutil.copy(run / previous.files["model"].name, run / f"{NAME}.zip")
    else:
        shutil.copy(run / newest.files["model"].name, run / f"{NAME}.zip")
        truncate(run / f"{NAME}.zip")

    assert not RunFolder(run).finished
    code, _out, err = zoo(["evaluate", "-f", str(logs), "--n-episodes", "1"])
    assert code == 2 and err[-1].startswith(f"sgfd-zoo evaluate: error: no finished run under {logs}")
    code, _out, err = zoo(["enjoy", "--algo", "sac", "--env", ENV_ID, "-f", str(logs), "-n", "10", "--no-render"])
    assert code == 2 and err[-1] == f"sgfd-zoo enjoy: error: no finished sac run of {ENV_ID} under {logs} " + (
        "(expected sac/<EnvName>_<id>/)"
    )
    jobs, done, _ = sweep.plan(logs, ["sac"], [ENV_ID], [0])
    assert done == [] and [(job.run_id, job.run.checkpoint.num_timesteps) for job in jobs] == [(1, 400)]


# -- configuration typos --------------------------------------------------------------------------------------

TYPOS = [
    (
        ["sac", "policy_kwargs:dict(net_archh=[32])"],
        "policy_kwargs of sac (MlpPolicy): 'net_archh' (did you mean 'net_arch'?)",
    ),
    (
        ["sgfd_sac", "policy:'EncoderMlpPolicy'", "policy_kwargs:dict(features_extractor_kwargs=dict(hiden_dim=8))"],
        "features_extractor_kwargs of sgfd_sac (MlpEncoder): 'hiden_dim' (did you mean 'hidden_dim'?)",
    ),
    (
        ["dbc", "representation_kwargs:'dict(bisim_coeff=0.5)'"],  # the "dict(...)" string form, as in a yaml
        "representation_kwargs of dbc ('dbc': DBCRepresentation): 'bisim_coeff' (did you mean 'bisim_coef'?)",
    ),
    (
        ["sac", "replay_buffer_kwargs:dict(frame_stak=3)"],
        "replay_buffer_kwargs of sac (DomainReplayBuffer): 'frame_stak' (did you mean 'frame_stack'?)",
    ),
]


@pytest.mark.parametrize("command", ["train", "optimize"])
@pytest.mark.parametrize(("params", "message"), TYPOS, ids=[typo[0][0] + " " + typo[0][-1][:20] for typo in TYPOS])
def test_a_typo_inside_a_kwargs_hyperparameter_is_one_line_naming_the_key_and_the_valid_ones(
    tmp_path: Path, command: str, params: list[str], message: str
) -> None:
    algo, *rest = params
    argv = [command, "--algo", algo, "--env", ENV_ID, "--quick", "-f", str(tmp_path / "logs"), "-params", *rest]
    code, _out, err = zoo(argv)
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith(f"sgfd-zoo {command}: error: unknown key(s) in ") and message in err[0]
    assert "; it takes " in err[0]
    assert not (tmp_path / "logs").exists()


def test_a_configuration_that_does_not_build_is_one_line_and_leaves_no_run_folder(tmp_path: Path) -> None:
    argv = ["train", "--algo", "sac", "--env", ENV_ID, "--quick", "-f", str(tmp_path / "logs")]
    # A bad value is refused where it enters, before the run folder is claimed.
    code, _out, err = zoo([*argv, "-params", "train_freq:(1, 'stepz')"])
    assert code == 2 and len(err) == 1, err
    assert err[0] == (
        "sgfd-zoo train: error: train_freq must be an int >= 1 or (int >= 1, 'step' or 'episode'), got (1, 'stepz')"
    )
    assert not (tmp_path / "logs").exists()
    # What only building finds (an activation that is not a module) fails there: the claimed folder goes again.
    code, _out, err = zoo([*argv, "-params", "policy_kwargs:dict(activation_fn='relu')"])
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith("sgfd-zoo train: error: sac on SGFD/MT-walker-walk-v0 cannot be built from this ")
    assert not (tmp_path / "logs").exists()


def test_the_sweep_refuses_a_typo_once_at_planning_before_any_run(tmp_path: Path) -> None:
    argv = ["sweep", "--algos", "sac", "--envs", ENV_ID, "--seeds", "0", "1", "-f", str(tmp_path), "--quick"]
    code, _out, err = zoo([*argv, "-params", "replay_buffer_kwargs:dict(frame_stak=3)"])
    assert code == 2 and len(err) == 1 and "'frame_stak' (did you mean 'frame_stack'?)" in err[0]
    # What only building the model finds is found at planning too: the pre-check builds each configuration.
    code, _out, err = zoo([*argv, "-params", "policy_kwargs:dict(activation_fn='relu')"])
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith("sgfd-zoo sweep: error: sac on SGFD/MT-walker-walk-v0 cannot be built from this ")
    assert not ray.is_initialized() and not list(tmp_path.iterdir())


def test_representation_kwargs_take_the_dict_string_form() -> None:
    argv = ["--algo", "dbc", "--env", ENV_ID, "--quick", "-params", "representation_kwargs:'dict(bisim_coef=0.25)'"]
    assert training.train(argv, check_only=True) == 0


# -- bad data -------------------------------------------------------------------------------------------------


def corrupt_one_step(monkeypatch: pytest.MonkeyPatch, at_call: int, damage: Callable[[tuple], tuple]) -> None:
    """Make the ``at_call``-th ``DMCEnv.step`` of this process (counted over every sub-env) return ``damage`` of
    its result: an env that produces bad data once."""
    real_step = sgfd_envs.dmc.DMCEnv.step
    calls = iter(range(1, 10**9))

    def step(self, action):
        result = real_step(self, action)
        return damage(result) if next(calls) == at_call else result

    monkeypatch.setattr(sgfd_envs.dmc.DMCEnv, "step", step)


def nan_reward(result: tuple) -> tuple:
    obs, _reward, terminated, truncated, info = result
    return obs, float("nan"), terminated, truncated, info


def unknown_domain(result: tuple) -> tuple:
    obs, reward, terminated, truncated, info = result
    return obs, reward, terminated, truncated, {**info, "domain": 9}


@pytest.mark.slow
@pytest.mark.parametrize(
    ("algo", "damage", "refusal"),
    [
        ("sac", nan_reward, r"refuses a non-finite reward \(nan\) at add 74 \(sub-env 2, domain 2\)"),
        ("sgfd_sac", unknown_domain, r"refuses domain label 9 .* at add 74 \(sub-env 2, domain 9\).*n_domains=4"),
    ],
)
def test_bad_data_from_an_env_stops_training_in_one_line_and_never_enters_the_buffer(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, algo: str, damage: Callable, refusal: str
) -> None:
    # 4 sub-envs: call 299 is sub-env 2's step in vector step 75 (add 74), after the checkpoint at 200 steps.
    corrupt_one_step(monkeypatch, 4 * 74 + 3, damage)
    logs = tmp_path / "logs"
    # SGFD's classifier within the run (it trains as SAC otherwise, with a warning)
    args = train_args(logs, *(["--classifier-start", "100"] if algo == "sgfd_sac" else []))
    args[args.index("sac")] = algo
    code, _out, err = zoo(args)
    run = logs / algo / f"{NAME}_1"
    assert code == 1 and len(err) == 1, err
    assert re.search(refusal, err[0]), err[0]
    assert "training stopped at 300 steps; its checkpoint at 200 steps is in" in err[0]
    assert not RunFolder(run).finished and leftovers(run) == []
    (checkpoint,) = read_index(run)
    buffer = load_from_pkl(run / checkpoint.files["replay_buffer"].name)
    stored = slice(0, buffer.size())
    assert numpy.isfinite(buffer.rewards[stored]).all() and (buffer.domains[stored] < 4).all()

    monkeypatch.undo()  # the env fixed
    code, out, err = zoo(printed_command(err[0], "continue it with: "))
    assert code == 0, err
    assert f"Resuming {run} from 200 steps" in out
    assert_finished(run, 400)
