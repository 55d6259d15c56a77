"""One run, one folder, one writer, as a cluster's batch system uses the zoo: runs started at the same moment into
one log folder (a SLURM array) each get a folder of their own, with their own seed, config and progress; a run
being trained is refused to a second writer (a ``--resume`` of it, a sweep) in one line naming the writer; the
lock of a writer that died is taken over with a one-line warning; SIGTERM (a job's time limit, a preemption)
stops training at a checkpoint; temporary files never collide.

The runs are ``sgfd-zoo train`` processes of the quick configuration of SAC on states, with a tiny network.
"""

from __future__ import annotations

import csv
import json
import os
import shlex
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from stable_baselines3 import SAC

import sgfd_envs
from sgfd_zoo.runs import locks
from sgfd_zoo.runs.checkpoint_callback import ResumableCheckpointCallback
from sgfd_zoo.runs.checkpoints import read_index
from sgfd_zoo.runs.files import TMP_PREFIX, temporary_path
from sgfd_zoo.runs.folders import STEPS_KEY, RunFolder, find_runs
from sgfd_zoo.runs.locks import LOCK_FILE, RunLock, RunLocked, live_holder, read_holder
from sgfd_zoo.sweep.plan import Job, locked_runs
from tests.zoo.zoo_runs import ENV_ID, NAME, SETTINGS, Training, has_checkpoint, train_args, zoo

# -- runs started together ---------------------------------------------------------------------------------


@pytest.mark.slow
def test_runs_started_together_each_get_their_own_folder_seed_config_and_progress(tmp_path: Path) -> None:
    # A SLURM array's tasks, into one log folder at once: two seeds, and one seed twice (a resubmitted task).
    logs, seeds = tmp_path / "logs", [0, 1, 2, 2]
    evaluations = ["--eval-freq", "200", "--eval-episodes", "1"]  # a row in progress.csv at the end
    started = [
        Training(train_args(logs, *evaluations, seed=seed, steps=200, save_freq=100), tmp_path / f"t{i}")
        for i, seed in enumerate(seeds)
    ]
    codes = [training.process.wait(timeout=600) for training in started]

    assert codes == [0, 0, 0, 0], [training.error_lines()[-3:] for training in started]
    runs = find_runs(logs)
    assert sorted(run.path.name for run in runs) == [f"{NAME}_{i}" for i in (1, 2, 3, 4)]
    assert sorted(run.seed for run in runs) == seeds
    log_paths = [training.out.read_text().split("Log path: ")[1].split()[0] for training in started]
    assert len(set(log_paths)) == 4  # each process says where it wrote, and no two say the same
    for seed, log_path in zip(seeds, log_paths, strict=True):
        run = RunFolder(Path(log_path))
        assert run.seed == seed and run.finished and read_holder(run.path) is None
        command = shlex.split((run.config_dir / "command.txt").read_text())
        assert command[:2] == ["sgfd-zoo", "train"] and command[command.index("--seed") + 1] == str(seed)
        assert yaml.load((run.config_dir / "config.yml").read_text(), Loader=yaml.UnsafeLoader)["buffer_size"] == 2000
        with (run.path / "progress.csv").open() as handle:
            assert sum(STEPS_KEY in line for line in handle) == 1  # one header: one writer
        with (run.path / "progress.csv").open() as handle:
            assert [int(float(row[STEPS_KEY])) for row in csv.DictReader(handle)] == [200]
        assert list(run.evaluations("train")["timesteps"]) == [200]
        assert not list(run.path.rglob(f"{TMP_PREFIX}*"))


def test_a_run_records_its_train_command_once_and_runs_of_earlier_versions_still_say_how_they_continue(
    tmp_path: Path,
) -> None:
    run = RunFolder(tmp_path / "sac" / f"{NAME}_1")
    argv = ["--algo", "sac", "--env", ENV_ID, "-params", "policy_kwargs:dict(net_arch=[32, 32])", "-f", "my logs"]
    # A run of an earlier version: rl-zoo3's unquoted command line (a sweep's: Ray's worker's) and command.json.
    run.config_dir.mkdir(parents=True)
    (run.config_dir / "command.txt").write_text("/venv/bin/python /venv/bin/ray-worker.py --node 1")
    (run.path / "command.json").write_text(json.dumps(argv))
    assert run.train_argv() == argv

    run.record_start({}, {}, [*argv, "--resume"], step=100)  # resumed by this version: one file, quoted
    assert sorted(path.name for path in run.path.iterdir()) == [NAME]
    assert (run.config_dir / "command.txt").read_text() == shlex.join(["sgfd-zoo", "train", *argv, "--resume"]) + "\n"
    assert run.train_argv() == [*argv, "--resume"]

    unknown = RunFolder(tmp_path / "sac" / f"{NAME}_2")  # started from Python: no command to record
    unknown.record_start({}, {}, None, step=0)
    assert not (unknown.config_dir / "command.txt").exists() and unknown.train_argv() is None
    legacy = Path(__file__).parents[1] / "data" / "legacy" / "0.1.0" / "train_folder" / "sgfd_sac" / f"{NAME}_1"
    assert (legacy / NAME / "command.txt").exists() and RunFolder(legacy).train_argv() is None  # never recorded flags


# -- a second writer ---------------------------------------------------------------------------------------


@pytest.mark.slow
def test_a_second_writer_is_refused_naming_the_holder_and_a_dead_ones_lock_is_taken_over(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    run = logs / "sac" / f"{NAME}_1"
    first = Training(train_args(logs, steps=100_000, save_freq=100), tmp_path / "first")
    first.wait_until(has_checkpoint(run))
    holder = f"pid {first.process.pid} on host {socket.gethostname()} (sgfd-zoo train --algo sac --env {ENV_ID} "

    # `--resume` of the run while it trains: one line naming the writer.
    code, _out, err = zoo(train_args(logs, "--resume", steps=100_000, save_freq=100))
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith(f"sgfd-zoo train: error: --resume: {run} is being written by {holder}"), err[0]
    assert "heartbeat " in err[0] and "one writer at a time" in err[0]
    # A sweep of it: the run is left alone, reported with its writer, and the sweep exits 1 (no Ray is started).
    sweep = ["sweep", "--algos", "sac", "--envs", ENV_ID, "--seeds", "0", "-f", str(logs), "--no-evaluate"]
    code, out, err = zoo([*sweep, *SETTINGS, "-n", "100000"])
    assert code == 1, (out, err)
    assert f"refused: {run} is being written by {holder}" in out and "this continues the sweep: sgfd-zoo sweep" in out

    # The writer is killed (no chance to give its lock back): the next --resume takes the lock over and finishes.
    first.process.kill()
    first.process.wait(timeout=60)
    assert read_holder(run) is not None
    stopped_at = read_index(run)[0].num_timesteps
    code, out, err = zoo(train_args(logs, "--resume", steps=stopped_at + 100, save_freq=100))
    assert code == 0, err
    warnings = [line for line in err if line.startswith("warning: taking over the lock")]
    assert len(warnings) == 1, err
    assert f"of {run} from pid {first.process.pid} on host {socket.gethostname()}" in warnings[0]
    assert warnings[0].endswith(f"its process (pid {first.process.pid} on {socket.gethostname()}) is gone")
    assert f"Resuming {run} from {stopped_at} steps" in out
    assert RunFolder(run).finished and read_holder(run) is None


def write_lock(folder: Path, host: str, pid: int, age: float) -> Path:
    """A lock file as another process on ``host`` wrote it, its last heartbeat ``age`` seconds ago."""
    path = folder / LOCK_FILE
    then = time.time() - age
    fields = {"token": "theirs", "pid": pid, "host": host, "pid_namespace": None, "started": then, "command": "x"}
    path.write_text(json.dumps(fields))
    os.utime(path, (then, then))
    return path


def test_a_lock_from_another_host_is_refused_while_its_heartbeat_is_fresh_and_taken_over_once_stale(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    write_lock(tmp_path, "node-17", 4242, age=20)
    with pytest.raises(RunLocked, match=r"is being written by pid 4242 on host node-17 \(x\) since .*, heartbeat 20 s"):
        RunLock.acquire(tmp_path, what="--resume")

    write_lock(tmp_path, "node-17", 4242, age=3600)  # that node was lost an hour ago
    lock = RunLock.acquire(tmp_path)
    try:
        warning = capsys.readouterr().err.strip()
        assert warning.startswith(f"warning: taking over the lock of {tmp_path} from pid 4242 on host node-17")
        assert warning.endswith("its heartbeat is 60 min old (more than 10 min)")
        assert read_holder(tmp_path).pid == os.getpid()
    finally:
        lock.release()
    assert read_holder(tmp_path) is None and not [p for p in tmp_path.iterdir() if p.name.startswith(".")]

    # A lock file cut short (its writer died writing it, on a file system without hard links): stale, taken over.
    (tmp_path / LOCK_FILE).write_text('{"token": "th')
    os.utime(tmp_path / LOCK_FILE, (time.time() - 3600, time.time() - 3600))
    RunLock.acquire(tmp_path).release()
    assert "its heartbeat is 60 min old" in capsys.readouterr().err


def test_a_sweep_leaves_a_run_a_live_writer_holds_and_plans_one_whose_writer_is_gone(tmp_path: Path) -> None:
    job = Job("sac", ENV_ID, 0, 1, tmp_path)
    job.run_dir.mkdir(parents=True)
    assert locked_runs([job]) == [] and live_holder(job.run_dir) is None  # no lock

    write_lock(job.run_dir, "node-17", 4242, age=20)
    assert live_holder(job.run_dir) == read_holder(job.run_dir)
    [(locked, line)] = locked_runs([job])
    assert locked == job and line.startswith(f"refused: {job.run_dir} is being written by pid 4242 on host node-17 (x)")
    assert line.endswith(", heartbeat 20 s ago (one writer at a time)"), line

    write_lock(job.run_dir, "node-17", 4242, age=3600)  # stale: the sweep's train takes it over
    assert live_holder(job.run_dir) is None and locked_runs([job]) == []


def test_the_heartbeat_renews_the_lock_and_a_writer_whose_lock_was_taken_over_stops_writing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(locks, "HEARTBEAT_SECONDS", 0.05)
    run = tmp_path / "run"
    run.mkdir()
    lock = RunLock.acquire(run)
    try:
        os.utime(lock.path, (1.0, 1.0))
        deadline = time.monotonic() + 10
        while lock.path.stat().st_mtime < time.time() - 60 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert lock.path.stat().st_mtime > time.time() - 60  # renewed
        lock.path.unlink()  # removed by hand: made again, the writer goes on
        while not lock.path.exists() and time.monotonic() < deadline:
            time.sleep(0.02)
        assert read_holder(run).pid == os.getpid() and lock.lost is None

        # Another process judged it stale (this one froze) and took it over.
        write_lock(run, "node-3", 99, age=0)
        while lock.lost is None and time.monotonic() < deadline:
            time.sleep(0.02)
        assert lock.lost is not None and f"the lock of {run} was taken over by pid 99 on host node-3" in lock.lost

        # Training with that lock stops at once, and writes no checkpoint.
        env = sgfd_envs.make_domain_vec_env(ENV_ID, obs_type="state")
        model = SAC("MlpPolicy", env, learning_starts=10, buffer_size=500, policy_kwargs={"net_arch": [8]})
        checkpointer = ResumableCheckpointCallback(1, run, lock=lock)
        model.learn(200, callback=checkpointer)
        assert checkpointer.taken_over == lock.lost and model.num_timesteps <= 2 * env.num_envs
        assert read_index(run) == []
    finally:
        lock.release()
    assert read_holder(run).host == "node-3"  # the new writer's lock stays


# -- SIGTERM ------------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_sigterm_stops_training_at_a_checkpoint_and_gives_the_lock_back(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    run = logs / "sac" / f"{NAME}_1"
    training = Training(train_args(logs, steps=100_000, save_freq=100_000), tmp_path / "job")
    training.wait_until((run / "progress.csv").exists)  # made when training starts

    training.process.send_signal(signal.SIGTERM)
    assert training.process.wait(timeout=300) == 143
    line = training.error_lines()[-1]
    stopped = read_index(run)[0].num_timesteps
    assert line.startswith(f"sgfd-zoo train: stopped: SIGTERM at {stopped} steps: its checkpoint at {stopped}"), line
    assert "continue it with: sgfd-zoo train " in line and line.endswith("--resume")
    assert read_holder(run) is None and not RunFolder(run).finished


# -- temporary files --------------------------------------------------------------------------------------


WRITE_MANY = """
import json, sys
from pathlib import Path
from sgfd_zoo.runs.files import atomic_write
content = json.dumps({"writer": sys.argv[2], "padding": "x" * 100_000})
for _ in range(40):
    atomic_write(Path(sys.argv[1]), lambda tmp: Path(tmp).write_text(content))
"""


def test_processes_writing_one_file_at_once_never_share_a_temporary_file(tmp_path: Path) -> None:
    target = tmp_path / "checkpoint.json"
    assert temporary_path(target) != temporary_path(target)
    assert f"-{os.getpid()}-" in temporary_path(target).name and temporary_path(target).name.endswith(target.name)
    writers = [
        subprocess.Popen([sys.executable, "-c", WRITE_MANY, str(target), marker], stderr=subprocess.PIPE, text=True)
        for marker in "ab"
    ]
    errors = [writer.communicate(timeout=120)[1] for writer in writers]
    assert [writer.returncode for writer in writers] == [0, 0], errors  # none lost its file to the other
    assert json.loads(target.read_text())["writer"] in "ab" and sorted(tmp_path.iterdir()) == [target]
