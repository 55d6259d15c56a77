"""``sgfd-zoo sweep``: run ids, argument errors, and real sweeps of tiny runs on real local Ray instances."""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import re
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import zipfile
from collections.abc import Iterator
from pathlib import Path

import pytest
import ray
import yaml

import sgfd_cli as cli
from sgfd_zoo.runs.checkpoints import Checkpoint, read_index, write_index
from sgfd_zoo.runs.files import atomic_write
from sgfd_zoo.runs.folders import RunFolder, find_runs, mark_finished
from sgfd_zoo.sweep import command as sweep
from sgfd_zoo.sweep import ray_runs

pytestmark = pytest.mark.ray

# ray is imported above, at collection: its log handler keeps the sys.stderr of its import, and one
# imported inside a test (under capsys) would write to a closed stream in the tests after it.

ENV = "SGFD/walker-walk-v0"
NAME = "SGFD-walker-walk-v0"
# Tiny runs: state observations, 600 steps (no gradient step before 1000), checkpoints at 300 and 600.
TINY = ["--quick", "-n", "600", "--eval-freq", "-1", "--save-freq", "300", "--verbose", "0"]


def write_zip(path: str, data: str = "not a model") -> None:
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("data", data)


def make_run(folder: Path, algo: str, run_id: int, seed: int, finished: bool = False, checkpoint: int = 0) -> Path:
    """A run folder as the zoo leaves it: args and config; if finished, a final model (a zip whose step count
    reached its total, as SB3 writes it) and the marker; a checkpoint (whole files, but not a loadable model)."""
    run = folder / algo / f"{NAME}_{run_id}"
    (run / NAME).mkdir(parents=True)
    (run / NAME / "args.yml").write_text(yaml.safe_dump({"seed": seed}))
    (run / NAME / "config.yml").write_text(yaml.safe_dump({}))
    if checkpoint:
        model = atomic_write(run / f"checkpoint_{checkpoint}_steps.zip", write_zip)
        write_index(run, [Checkpoint(checkpoint, {"model": model})])
    if finished:
        mark_finished(run, atomic_write(run / f"{NAME}.zip", write_zip), max(checkpoint, 100))
    return run


def test_plan_skips_finished_runs_resumes_checkpoints_and_never_shares_a_folder(tmp_path: Path) -> None:
    # A sweep gives seed s the folder <EnvName>_<s + 1> (rl-zoo3 numbers runs from 1) when it is free.
    make_run(tmp_path, "sgfd_sac", 4, seed=0, finished=True)  # seed 0 done by `sgfd-zoo train`
    make_run(tmp_path, "sgfd_sac", 2, seed=1, checkpoint=200)
    make_run(tmp_path, "sgfd_sac", 6, seed=1, checkpoint=600)  # the furthest checkpoint of seed 1
    make_run(tmp_path, "sgfd_sac", 3, seed=9)  # another seed's run sits in seed 2's folder
    make_run(tmp_path, "sgfd_sac", 5, seed=7)  # ... and in seed 4's

    jobs, done, problems = sweep.plan(tmp_path, ["sgfd_sac", "sac"], [ENV], [0, 1, 2, 4])

    assert done == [("sgfd_sac", ENV, 0)] and problems == []
    ids = {(job.algo, job.seed): job.run_id for job in jobs}
    assert ids == {
        ("sac", 0): 1,
        ("sgfd_sac", 1): 6,
        ("sac", 1): 2,
        ("sgfd_sac", 2): 7,
        ("sac", 2): 3,
        ("sgfd_sac", 4): 8,
        ("sac", 4): 5,
    }
    assert [job.seed for job in jobs] == [0, 1, 1, 2, 2, 4, 4]  # seed by seed: whole tables fill up first
    assert jobs[1].run_dir == tmp_path / "sgfd_sac" / f"{NAME}_6"

    # Seed 2 started in its new folder and crashed before a checkpoint: the next sweep restarts it there.
    make_run(tmp_path, "sgfd_sac", 7, seed=2)
    again = {(job.algo, job.seed): job.run_id for job in sweep.plan(tmp_path, ["sgfd_sac"], [ENV], [2, 4])[0]}
    assert again == {("sgfd_sac", 2): 7, ("sgfd_sac", 4): 8}


def test_plan_reports_a_broken_run_folder_and_goes_on(tmp_path: Path) -> None:
    resumable = make_run(tmp_path, "sgfd_sac", 1, seed=0, checkpoint=300)
    (resumable / "checkpoint.json").write_bytes(b"\0" * 40)  # zeroed: its checkpoint files are still there
    unknown = make_run(tmp_path, "sgfd_sac", 2, seed=1)
    (unknown / NAME / "args.yml").write_text("seed: [1")  # cut short
    make_run(tmp_path, "sgfd_sac", 3, seed=2, finished=True)
    (tmp_path / "sgfd_sac" / f"{NAME}_3" / "finished.json").write_text('{"num_timesteps": 1')

    jobs, done, problems = sweep.plan(tmp_path, ["sgfd_sac"], [ENV], [0, 1, 2])

    # Seed 0 resumes from the checkpoint its files make up; seed 1's folder has no known seed, so seed 1 starts
    # there (it has nothing to lose); the marker of seed 2's run is unreadable, its final model is not whole.
    assert {job.seed: job.run_id for job in jobs} == {0: 1, 1: 2, 2: 3} and done == []
    assert len(problems) == 3 and all(" is unreadable (" in problem for problem in problems)
    assert any(str(resumable / "checkpoint.json") in problem for problem in problems)
    assert RunFolder(resumable).checkpoint.num_timesteps == 300


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--algos", "sgfd"], "--algos: 'sgfd' is unknown (did you mean sgfd_sac?)"),
        (
            ["--envs", "SGFD/walker-wlk-v0"],
            "--envs: 'SGFD/walker-wlk-v0' is unknown (did you mean SGFD/walker-walk-v0?)",
        ),
        (["--seeds", "-1"], "--seeds: -1 is not in 0.."),
        (["--seed", "3"], "--seed is set per run by the sweep; use --seeds"),
        (["--resume"], "--resume is set per run by the sweep"),
        (["--cpus-per-run", "0"], "--cpus-per-run must be > 0"),
        (["--num-cpus", "1", "--cpus-per-run", "2"], "--cpus-per-run 2 is more than the 1 CPUs"),
        (["--address", "127.0.0.1:6379", "--num-cpus", "2"], "--num-cpus sizes the local Ray instance"),
        (["--address", "127.0.0.1:{port}"], "--address 127.0.0.1:{port}: no Ray cluster answers there"),
    ],
)
def test_bad_arguments_exit_2_with_one_line_naming_the_argument(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], message: str
) -> None:
    port = _free_port()
    argv = ["--algos", "sgfd_sac", "--envs", ENV, "--seeds", "0", "-f", str(tmp_path / "logs")]
    # Later flags win: each case overrides one of the valid ones above.
    argv += [arg.format(port=port) for arg in extra]
    assert cli.main(["sweep", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("sgfd-zoo sweep: error: ")
    assert message.format(port=port) in err[-1]
    assert not any(line.startswith("Traceback") for line in err)
    assert not (tmp_path / "logs").exists()


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--algos", "sac", "-params", "n_rff:2"], "unknown hyperparameter(s) for sac: 'n_rff'"),
        # the paper-scale configuration (pixel encoder) on states: the flag that fits is named
        (["--env-kwargs", "obs_type:'state'"], "but the env gives state observations: use --quick"),
    ],
)
def test_a_configuration_that_does_not_fit_is_refused_in_one_line_before_any_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], message: str
) -> None:
    argv = ["--algos", "sgfd_sac", "--envs", "SGFD/MT-cheetah-run-v0", "--seeds", "0", "1", "-f", str(tmp_path)]
    argv += ["-n", "300", "--num-cpus", "1", *extra]
    if extra[0] == "--algos":
        argv += ["--quick"]  # the n_rff case is about the algorithm, on the quick configuration
    assert cli.main(["sweep", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("sgfd-zoo sweep: error: ") and message in err[0]
    assert not ray.is_initialized() and not list(tmp_path.iterdir())


@pytest.fixture(scope="module")
def first_sweep(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, int, str]:
    """
    Two tiny SGFD runs and two SAC runs that fail (each "crashed" earlier, leaving a checkpoint that is whole,
    as written, but no model: resuming it fails, and the sweep must not start it again over it), on a local
    Ray instance the sweep starts itself; then the evaluation of what finished. SGFD's seed 1 "crashed" too,
    leaving a checkpoint whose model was zeroed since: none of its checkpoints verifies, so it starts again.
    """
    folder = tmp_path_factory.mktemp("sweep") / "logs"
    for seed in (0, 1):
        make_run(folder, "sac", seed + 1, seed=seed, checkpoint=300)
    zeroed = make_run(folder, "sgfd_sac", 2, seed=1, checkpoint=300) / "checkpoint_300_steps.zip"
    zeroed.write_bytes(bytes(zeroed.stat().st_size))
    argv = ["sweep", "--algos", "sgfd_sac", "sac", "--envs", ENV, "--seeds", "0", "1", "-f", str(folder)]
    argv += ["--num-cpus", "2", "--n-episodes", "1", *TINY]
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = cli.main(argv)
    return folder, code, out.getvalue()


@pytest.mark.slow
def test_sweep_trains_each_seed_into_its_own_folder_reports_failures_and_evaluates(
    first_sweep: tuple[Path, int, str],
) -> None:
    folder, code, out = first_sweep
    assert not ray.is_initialized()  # the sweep shut its Ray instance down
    assert code == 1, out
    runs = sorted(find_runs(folder), key=lambda run: run.seed)
    assert [(run.algo, run.seed, run.path.name) for run in runs] == [
        ("sgfd_sac", 0, f"{NAME}_1"),
        ("sgfd_sac", 1, f"{NAME}_2"),
    ]
    for run in runs:
        log = run.path.with_name(f"{run.path.name}.log").read_text()
        assert f"sgfd_sac on {ENV} seed {run.seed}" in log
    logs = [run.path.with_name(f"{run.path.name}.log").read_text() for run in runs]
    assert "(new run)" in logs[0] and "(resuming from its checkpoint)" in logs[1]
    assert "--resume: no usable checkpoint in " in logs[1] and "=== so starting it again from step 0" in logs[1]
    assert not (runs[1].path / "progress_from_300.csv").exists()
    # The failures: in the summary with their reason and log, and no run folder left behind; then the command
    # that continues the sweep.
    summary = out[out.rindex("\nsweep: 2 trained") + 1 :]
    assert summary.startswith("sweep: 2 trained, 0 already finished, 2 failed\n")
    continues = summary.splitlines()[-1]
    assert continues.startswith("sweep: not every run finished; once the failures are fixed, this continues the sweep")
    assert continues.endswith(
        f"sgfd-zoo sweep --algos sgfd_sac sac --envs {ENV} --seeds 0 1 -f {folder} --num-cpus 2 "
        f"--n-episodes 1 {' '.join(TINY)}"
    )
    for seed in (0, 1):
        log = folder / "sac" / f"{NAME}_{seed + 1}.log"
        assert f"FAILED sac on {ENV} seed {seed}: " in summary and "checkpoint_300_steps" in summary
        assert f"(its checkpoint at 300 steps is kept; log: {log})" in summary
        assert "resuming from its checkpoint" in log.read_text() and "Traceback" not in log.read_text()
        assert "sgfd-zoo train: --resume: " in log.read_text()  # the zoo's one line, in the run's log too
        assert "passes its checks but does not load" in summary
        failed = RunFolder(folder / "sac" / f"{NAME}_{seed + 1}")
        assert not failed.finished and failed.checkpoint is not None  # kept as it was, for a fixed code to resume
    # A line per run as it ends, and the final progress block counts them all.
    assert f"finished sgfd_sac on {ENV} seed 1" in out and f"FAILED sac on {ENV} seed 0" in out
    assert out.rsplit("--- sweep progress ", 1)[1].splitlines()[1] == "0 running, 0 waiting, 2 finished, 2 failed"
    # The tables cover what finished.
    with (folder / "results.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert {(row["algo"], row["seed"], row["split"]) for row in rows} == {
        ("sgfd_sac", seed, split) for seed in ("0", "1") for split in ("train", "test")
    }
    # (SGFD/walker-walk-v0 without background_dir plays sgfd_envs' procedural backgrounds: the table says so)
    assert "# train (stand-in) (mean ± std over 2 seeds)" in out


@pytest.mark.slow
def test_the_sweep_goes_on_when_its_progress_board_dies(tmp_path: Path) -> None:
    killed = threading.Event()

    def kill_the_board() -> None:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline:
            try:
                # (a Ray call before the sweep's ray.init would start an instance of its own)
                if ray.is_initialized():
                    ray.kill(ray.get_actor(ray_runs.BOARD_NAME))
                    killed.set()
                    return
            except ValueError:  # no board yet
                pass
            time.sleep(0.2)

    killer = threading.Thread(target=kill_the_board, daemon=True)
    killer.start()
    argv = ["sweep", "--algos", "sac", "--envs", ENV, "--seeds", "0", "-f", str(tmp_path), "--num-cpus", "1"]
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = cli.main([*argv, "--no-evaluate", *TINY])
    killer.join(timeout=5)
    assert killed.is_set(), "the board was never seen"
    assert code == 0, out.getvalue()
    assert "sweep: the progress board stopped (ActorDiedError: " in out.getvalue(), out.getvalue()
    assert f"[1/1] finished sac on {ENV} seed 0" in out.getvalue()
    assert [run.path.name for run in find_runs(tmp_path)] == [f"{NAME}_1"]


@pytest.fixture
def ray_cluster() -> Iterator[str]:
    """A Ray instance of this test process, standing for an existing cluster; its address."""
    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        yield ray.get_runtime_context().gcs_address
    finally:
        ray.shutdown()


@pytest.mark.slow
def test_sweep_on_an_existing_cluster_skips_finished_runs_and_resumes_a_crashed_one(
    first_sweep: tuple[Path, int, str], ray_cluster: str, tmp_path: Path
) -> None:
    folder = tmp_path / "logs"
    shutil.copytree(first_sweep[0], folder)
    # Seed 0 "crashed" after its last checkpoint (600 steps): no final model. Seed 1 is finished.
    crashed = folder / "sgfd_sac" / f"{NAME}_1"
    (crashed / f"{NAME}.zip").unlink()
    finished_model = folder / "sgfd_sac" / f"{NAME}_2" / f"{NAME}.zip"
    finished_mtime = finished_model.stat().st_mtime_ns

    argv = ["sweep", "--algos", "sgfd_sac", "--envs", ENV, "--seeds", "0", "1", "-f", str(folder)]
    argv += ["--address", ray_cluster, "--no-evaluate", *TINY, "-n", "900"]  # the resumed run goes on to 900
    result = subprocess.run(
        [sys.executable, "-m", "sgfd_cli", *argv],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert "1 finished already, 1 to train (1 to resume)" in result.stdout
    assert f"[1/1] finished sgfd_sac on {ENV} seed 0 (resumed)" in result.stdout and f"({crashed})" in result.stdout
    assert finished_model.stat().st_mtime_ns == finished_mtime
    # Continued, not restarted: same folder, a log from step 600 on, a checkpoint at 900, the final model.
    assert (crashed / "progress_from_600.csv").exists()
    assert [checkpoint.num_timesteps for checkpoint in read_index(crashed)] == [900, 600]
    assert (crashed / f"{NAME}.zip").exists()
    assert sorted(path.name for path in (folder / "sgfd_sac").iterdir() if path.is_dir()) == [f"{NAME}_1", f"{NAME}_2"]
    log = (folder / "sgfd_sac" / f"{NAME}_1.log").read_text()
    assert "(new run)" in log and "(resuming from its checkpoint)" in log  # appended, the first attempt kept


@pytest.mark.slow
def test_a_sweep_on_a_gpu_node_packs_its_runs_by_the_rule(tmp_path: Path) -> None:
    """A Ray instance that declares one GPU and 4 CPUs stands for a GPU node (Ray schedules by what a node declares;
    the tiny run itself trains on the CPU here): the rule packs 2 runs on the GPU, each reserving half of it and 2
    CPUs, with 1 torch thread and its 4 training envs in processes of their own."""
    ray.init(address="local", num_cpus=4, num_gpus=1, include_dashboard=False, log_to_driver=False)
    try:
        argv = ["sweep", "--algos", "sac", "--envs", ENV, "--seeds", "0", "-f", str(tmp_path / "logs")]
        argv += ["--address", ray.get_runtime_context().gcs_address, "--no-evaluate", *TINY]
        result = subprocess.run(
            [sys.executable, "-m", "sgfd_cli", *argv], capture_output=True, text=True, timeout=600, cwd=tmp_path
        )
    finally:
        ray.shutdown()
    assert result.returncode == 0, result.stdout + result.stderr
    packed = "sweep: 2 runs per GPU (--gpus-per-run 0.5); each 2 CPUs, 1 torch thread and 4 env processes"
    assert packed in result.stdout
    (run,) = find_runs(tmp_path / "logs")
    assert (run.args["vec_env"], run.args["num_threads"]) == ("subproc", 1)


@pytest.mark.slow
def test_ctrl_c_stops_each_running_run_at_a_checkpoint_that_the_same_command_resumes(tmp_path: Path) -> None:
    # A long run without periodic checkpoints: whatever checkpoint it has, the Ctrl-C wrote.
    argv = ["sweep", "--algos", "sac", "--envs", ENV, "--seeds", "0", "1", "-f", str(tmp_path / "logs")]
    argv += ["--num-cpus", "1", "--no-evaluate", "--progress-interval", "0.5"]
    argv += ["--quick", "-n", "100000", "--eval-freq", "-1", "--save-freq", "100000", "--verbose", "0"]
    out_file = tmp_path / "out.txt"
    with out_file.open("w") as out:
        # A process group of its own, as a terminal's foreground job: the Ctrl-C reaches the sweep and Ray's
        # own processes alike. Its SIGINT is a terminal's too: a test run started in the background (nohup, &)
        # ignores SIGINT, and a Python started ignoring it never raises KeyboardInterrupt.
        sweep_process = subprocess.Popen(
            [sys.executable, "-m", "sgfd_cli", *argv],
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
        )
        try:
            deadline, seen = time.monotonic() + 300, 0
            while seen < 1100 and time.monotonic() < deadline and sweep_process.poll() is None:  # past learning_starts
                steps = re.findall(r"sac walker-walk seed 0 +(\d+)/100000", out_file.read_text())
                seen = int(steps[-1]) if steps else 0
                time.sleep(0.5)
            assert seen >= 1100, out_file.read_text()
            os.killpg(sweep_process.pid, signal.SIGINT)
            code = sweep_process.wait(timeout=180)
        finally:
            if sweep_process.poll() is None:
                os.killpg(sweep_process.pid, signal.SIGKILL)
    text = out_file.read_text()
    assert code == 130, text
    run = RunFolder(tmp_path / "logs" / "sac" / f"{NAME}_1")
    assert not run.finished and run.checkpoint is not None, text
    stopped_at = run.checkpoint.num_timesteps
    assert seen <= stopped_at < 100000
    assert f"stopped sac on {ENV} seed 0 at its checkpoint at {stopped_at} steps ({run.path})" in text
    assert "sweep: interrupted; the same command resumes it" in text
    log = run.path.with_name(f"{run.path.name}.log").read_text()
    assert f"sgfd-zoo train: Ctrl-C at {stopped_at} steps" in log and "Traceback" not in log
    # Seed 1 was waiting: it never started. The same command resumes seed 0 from the Ctrl-C's checkpoint.
    jobs, done, problems = sweep.plan(tmp_path / "logs", ["sac"], [ENV], [0, 1])
    assert [(job.seed, job.run_dir, job.run.checkpoint) for job in jobs] == [
        (0, run.path, run.checkpoint),
        (1, tmp_path / "logs" / "sac" / f"{NAME}_2", None),
    ]
    assert done == [] and problems == []


# -- a `ray start` cluster: token authentication, and a cluster that goes away ----------------------------

TINY_PARAMS = [
    "-params",
    "learning_starts:100",
    "gradient_steps:1",
    "batch_size:32",
    "policy_kwargs:dict(net_arch=[32])",
]


def _processes_under(marker: str) -> list[int]:
    """The pids of the processes whose command line names ``marker`` (a cluster's own temp dir), and their
    descendants: what `ray start` started for one test, and nothing else on the machine."""
    parents: dict[int, int] = {}
    found = set()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            command = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            parents[int(entry.name)] = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            continue
        if marker in command:
            found.add(int(entry.name))
    grown = True
    while grown:
        children = {pid for pid, parent in parents.items() if parent in found} - found
        found |= children
        grown = bool(children)
    return sorted(found)


def _kill(pids: list[int]) -> None:
    for pid in pids:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)


@contextlib.contextmanager
def ray_start_cluster(home: Path, token: bool) -> Iterator[tuple[str, str]]:
    """``ray start --head`` on this machine, with HOME ``home`` (where Ray keeps its token) and a temp dir of its
    own; yields its address and that temp dir. Stopped by killing its processes by pid (``ray stop`` would stop
    every Ray instance on the machine)."""
    home.mkdir(parents=True, exist_ok=True)
    env = {key: value for key, value in os.environ.items() if not key.startswith("RAY_AUTH")}
    env["HOME"] = str(home)
    ray_command = [str(Path(sys.executable).with_name("ray"))]
    if token:  # what a first `ray.init()` on this machine leaves: then `ray start` turns authentication on
        subprocess.run([*ray_command, "get-auth-token", "--generate"], env=env, check=True, capture_output=True)
    temp = tempfile.mkdtemp(prefix="rc", dir="/tmp")  # short: Ray's socket paths have a length limit
    port = _free_port()
    started = [*ray_command, "start", "--head", f"--port={port}", "--num-cpus=1", f"--temp-dir={temp}"]
    started += ["--include-dashboard=false", "--disable-usage-stats"]
    try:
        subprocess.run(started, env=env, check=True, capture_output=True, timeout=300)
        yield f"127.0.0.1:{port}", temp
    finally:
        _kill(_processes_under(temp))
        shutil.rmtree(temp, ignore_errors=True)


def _sweep_env(home: Path) -> dict[str, str]:
    env = {key: value for key, value in os.environ.items() if not key.startswith("RAY_AUTH")}
    return {**env, "HOME": str(home)}


@pytest.mark.slow
def test_sweep_attaches_to_a_ray_start_cluster_with_token_authentication(tmp_path: Path) -> None:
    head, elsewhere, logs = tmp_path / "head", tmp_path / "elsewhere", tmp_path / "logs"
    elsewhere.mkdir()
    with ray_start_cluster(head, token=True) as (address, _temp):
        argv = [sys.executable, "-m", "sgfd_cli", "sweep", "--algos", "sac", "--envs", ENV, "--seeds", "0"]
        argv += ["-f", str(logs), "--address", address, "--no-evaluate", *TINY]
        # A machine without the cluster's token: one line naming authentication and what to do.
        refused = subprocess.run(argv, env=_sweep_env(elsewhere), capture_output=True, text=True, timeout=300)
        assert refused.returncode == 2, refused.stdout + refused.stderr
        last = refused.stderr.strip().splitlines()[-1]
        assert last.startswith(f"sgfd-zoo sweep: error: --address {address}: the Ray cluster requires token auth")
        assert "this machine has no token" in last and "~/.ray/auth_token" in last and "RAY_AUTH_TOKEN" in last
        assert "InvalidAuthToken" not in refused.stderr and not list(logs.glob("*/*/"))
        # The cluster's own machine has the token: attached, the run trains.
        done = subprocess.run(argv, env=_sweep_env(head), capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert f"sweep: Ray cluster at {address}: 1 CPUs" in done.stdout
    (run,) = find_runs(logs)
    # The run's command.txt is the train command the sweep ran (not Ray's worker command line).
    command = shlex.split((run.config_dir / "command.txt").read_text())
    assert command[:9] == ["sgfd-zoo", "train", "--algo", "sac", "--env", ENV, "--seed", "0", "-f"]
    assert command[command.index("--run-id") + 1] == "1" and "default_worker" not in " ".join(command)


LISTENING = """
import argparse, json, psutil
from sgfd_zoo.sweep import ray_runs
ray_runs.start_ray(argparse.Namespace(address=None, num_cpus=1, ray_logs=False, gpus_per_run=0.0))
import ray  # as the sweep imports it: after its environment is set
try:
    assert ray.get(ray.remote(lambda: 1).remote()) == 1  # a worker process, listening too
    nodes = [node["NodeManagerAddress"] for node in ray.nodes()]
    processes = {process.pid: process.name() for process in psutil.Process().children(recursive=True)}
    listening = [
        (processes[connection.pid], connection.laddr.ip)
        for connection in psutil.net_connections("inet")
        if connection.status == psutil.CONN_LISTEN and connection.pid in processes
    ]
finally:
    ray.shutdown()
print(json.dumps({"nodes": nodes, "listening": listening}))
"""


@pytest.mark.slow
def test_a_local_sweeps_ray_listens_on_loopback_only() -> None:
    # In a process of its own, as `sgfd-zoo sweep` runs, without the tests' setting (conftest.py): the zoo's own
    # environment for Ray, set before Ray is imported, binds the instance to loopback.
    env = {key: value for key, value in os.environ.items() if key != ray_runs.CLUSTERS_VARIABLE}
    result = subprocess.run([sys.executable, "-c", LISTENING], env=env, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    found = json.loads(result.stdout.strip().splitlines()[-1])
    assert found["nodes"] == ["127.0.0.1"]
    listening = found["listening"]
    assert {"gcs_server", "raylet"} <= {name for name, _ in listening}, listening
    assert all(ip in ("127.0.0.1", "::ffff:127.0.0.1", "::1") for _, ip in listening), listening


def test_liveness_counts_a_head_that_stops_taking_connections_as_lost_after_failures_in_a_row() -> None:
    with socket.create_server(("127.0.0.1", 0)) as server:
        address = f"127.0.0.1:{server.getsockname()[1]}"
        liveness = ray_runs.Liveness(address)
        liveness.check(now=True)  # it answers
        assert liveness.failures == 0
    for failures in range(1, ray_runs.LIVENESS_FAILURES):  # closed: a failure short of the count is not yet lost
        liveness._next = 0.0  # the check is due
        liveness.check()
        assert liveness.failures == failures
    liveness._next = 0.0
    with pytest.raises(ray_runs.ClusterLost, match=f"its head at {re.escape(address)} no longer answers"):
        liveness.check()


@pytest.mark.slow
def test_a_sweep_whose_cluster_goes_away_exits_75_naming_it_with_where_each_run_stopped(tmp_path: Path) -> None:
    home, logs = tmp_path / "home", tmp_path / "logs"
    out_file = tmp_path / "out.txt"
    # Long runs with a checkpoint every 200 steps, one at a time (the cluster has 1 CPU): seed 1 waits.
    flags = ["--quick", "-n", "100000", "--eval-freq", "-1", "--save-freq", "200", "--verbose", "0", *TINY_PARAMS]
    with ray_start_cluster(home, token=False) as (address, temp):
        argv = ["sweep", "--algos", "sac", "--envs", ENV, "--seeds", "0", "1", "-f", str(logs), "--address", address]
        argv += ["--no-evaluate", "--progress-interval", "1", *flags]
        with out_file.open("w") as out:
            process = subprocess.Popen(
                [sys.executable, "-m", "sgfd_cli", *argv],
                stdout=out,
                stderr=subprocess.STDOUT,
                env=_sweep_env(home),
            )
        try:
            run = logs / "sac" / f"{NAME}_1"
            deadline = time.monotonic() + 400
            while time.monotonic() < deadline and process.poll() is None:
                with contextlib.suppress(Exception):
                    if read_index(run):
                        break
                time.sleep(0.5)
            assert read_index(run), out_file.read_text()
            _kill(_processes_under(temp))  # the cluster goes away: head, raylet, workers
            lost_at = time.monotonic()
            code = process.wait(timeout=120)
        finally:
            if process.poll() is None:
                process.kill()
    text = out_file.read_text()
    assert code == 75, text
    assert time.monotonic() - lost_at < 60  # before Ray's own minute
    stopped_at = RunFolder(run).checkpoint.num_timesteps
    assert f"stopped at its checkpoint at {stopped_at} steps: sac on {ENV} seed 0 ({run})" in text or (
        f"FAILED sac on {ENV} seed 0: " in text and f"its checkpoint at {stopped_at} steps is kept" in text
    ), text
    assert f"not started: sac on {ENV} seed 1 ({logs / 'sac' / f'{NAME}_2'})" in text
    last = text.strip().splitlines()[-1]
    assert last.startswith(f"sweep: the Ray cluster at {address} went away: its head at ")
    assert (
        "every checkpoint is kept: on a running cluster, this continues the sweep: sgfd-zoo sweep --algos sac" in last
    )
    assert not RunFolder(run).finished and stopped_at >= 200
