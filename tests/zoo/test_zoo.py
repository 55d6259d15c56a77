"""The sgfd-zoo command: train, evaluate, plot, resume and optimize through the console script."""

import csv
import json
import os
import re
import signal
import subprocess
import sys
import time
from argparse import Namespace

import numpy as np
import pytest
import torch as th
import yaml

import sgfd_envs
from sgfd_cli import main as zoo_main
from sgfd_zoo import training
from sgfd_zoo.algos import SGFD_ALGOS, hyperparams_file
from sgfd_zoo.arguments import ZooError
from sgfd_zoo.experiment import SGFDExperimentManager, register_algorithms
from sgfd_zoo.report.evaluate import read_results, render_tables
from sgfd_zoo.runs import provenance
from sgfd_zoo.runs.checkpoints import read_index
from sgfd_zoo.runs.folders import RunFolder

ENV_ID = "SGFD/MT-walker-walk-v0"
RUN_NAME = "SGFD-MT-walker-walk-v0"
# A tiny state-observation run: the quick configuration cut to a few hundred steps.
TINY = ["--quick", "-n", "800", "--num-threads", "1", "--no-progress", "--verbose", "0"]
TINY_PARAMS = ["-params", "learning_starts:200", "classifier_start:300", "policy_kwargs:dict(net_arch=[32])"]


def zoo(*args: str, check: bool = True, timeout: float = 600) -> subprocess.CompletedProcess:
    result = subprocess.run(
        [sys.executable, "-m", "sgfd_cli", *args], capture_output=True, text=True, timeout=timeout, check=False
    )
    if check and result.returncode != 0:
        raise AssertionError(f"sgfd-zoo {' '.join(args)} failed:\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}")
    return result


@pytest.mark.slow
def test_train_both_algorithms_then_evaluate_and_plot(tmp_path):
    logs = tmp_path / "logs"
    for algo in ("sgfd_sac", "sac"):
        params = TINY_PARAMS if algo == "sgfd_sac" else TINY_PARAMS[:2] + TINY_PARAMS[3:]
        zoo("train", "--algo", algo, "--env", ENV_ID, "-f", str(logs), "--seed", "3", "--eval-freq", "200",
            "--eval-episodes", "1", *TINY, "-n", "400", *params)  # fmt: skip

    sgfd_run = logs / "sgfd_sac" / f"{RUN_NAME}_1"
    assert (sgfd_run / f"{RUN_NAME}.zip").exists()
    # Evaluation during training covers every split, with the yaml's env kwargs (state observations).
    for split in ("train", "interpolation", "extrapolation"):
        with np.load(sgfd_run / f"evaluations_{split}.npz") as data:
            assert data["timesteps"].tolist() == [200, 400]
            assert data["results"].shape == (2, 1)
    with (sgfd_run / "progress.csv").open() as handle:
        columns = next(csv.reader(handle))
    assert {"sgfd/classifier_accuracy", "eval/extrapolation/mean_reward"} <= set(columns)
    config = yaml.load((sgfd_run / RUN_NAME / "config.yml").read_text(), Loader=yaml.UnsafeLoader)
    assert config["env_kwargs"] == {"obs_type": "state", "observe_parameter": True}
    assert config["classifier_start"] == 300
    # Without --save-freq a run checkpoints every fifth of its steps (the two newest kept), so a kill of a short
    # run costs a fifth of it, not all of it.
    assert [checkpoint.num_timesteps for checkpoint in read_index(sgfd_run)] == [400, 320]

    result = zoo("evaluate", "-f", str(logs), "--n-episodes", "2")
    rows = read_results(logs / "results.csv")
    assert {(row["algo"], row["split"]) for row in rows} == {
        (algo, split) for algo in ("sgfd_sac", "sac") for split in ("train", "interpolation", "extrapolation")
    }
    assert all(row["seed"] == "3" and row["n_episodes"] == "2" for row in rows)
    table = (logs / "results.md").read_text()
    assert table in result.stdout
    for heading in ("# train", "# interpolation", "# extrapolation", "MT-walker-walk", "**Total**"):
        assert heading in table
    header = next(line for line in table.splitlines() if "Task" in line)
    assert [cell.strip() for cell in header.strip("|").split("|")] == ["Task", "SGFD", "DR"]
    # Evaluated again with the same settings: each run's kept evaluation is reused, not recomputed.
    kept = sgfd_run / "final_evaluation.json"
    stamp = kept.stat().st_mtime_ns
    again = zoo("evaluate", "-f", str(logs), "--n-episodes", "2")
    assert kept.stat().st_mtime_ns == stamp and read_results(logs / "results.csv") == rows
    assert table in again.stdout
    zoo("evaluate", "-f", str(logs), "--n-episodes", "1")  # other settings: evaluated anew
    assert kept.stat().st_mtime_ns > stamp
    assert all(row["n_episodes"] == "1" for row in read_results(logs / "results.csv"))

    zoo("plot", "-f", str(logs))
    png = logs / "plots" / f"{RUN_NAME}.png"
    assert png.stat().st_size > 10_000


@pytest.mark.parametrize("quick", [False, True])
@pytest.mark.parametrize("algo", sorted(SGFD_ALGOS))
@pytest.mark.slow
def test_every_yaml_entry_builds_its_model(algo, quick, tmp_path):
    register_algorithms()
    entries = yaml.safe_load(hyperparams_file(algo, quick).read_text())
    env_ids = sgfd_envs.SGFD_IDS if not quick else sgfd_envs.SGFD_IDS[:1] + sgfd_envs.SGFD_IDS[5:6]
    assert quick or set(sgfd_envs.SGFD_IDS) <= set(entries), "an SGFD id has no paper-scale entry"
    for env_id in env_ids:
        manager = SGFDExperimentManager(
            Namespace(), algo, env_id, str(tmp_path), eval_freq=-1, quick=quick, seed=0, verbose=0, device="cpu"
        )
        model, saved = manager.setup_experiment()
        expected = SGFD_ALGOS[algo].algo_class
        assert type(model) is expected
        assert model.n_envs == sgfd_envs.n_domains(env_id, "train")
        for key, value in SGFD_ALGOS[algo].overrides.items():  # SGFD's settings (model.sgfd)
            assert getattr(model.sgfd, key) == value and saved[key] == value
        if not quick:
            # The paper's setting: pixels, 3 stacked frames, frame-deduplicating buffer of its 1e6 transitions; the
            # authors' cadence: 1000 updates at once, then one per 5 transitions of the 4 training domains.
            assert (model.observation_space.shape, model.replay_buffer.frame_stack) == ((9, 84, 84), 3)
            assert model.replay_buffer.buffer_size * model.n_envs == 1_000_000 and model.gradient_steps == 4
            assert (model.train_freq.frequency, type(manager.callbacks[0]).__name__) == (5, "UpdateBurst")
            # tau: the paper's 0.01; sgfd_sac_official.yml holds the authors' code's run settings (critic_tau 0.005).
            tau = 0.005 if SGFD_ALGOS[algo].hyperparams == "sgfd_sac_official" else 0.01
            assert (model.batch_size, model.lr_schedule(1), model.tau) == (128, 1e-3, tau)
        model.env.close()
        del model


def test_table_renders_in_the_papers_layout():
    rows = [
        {"algo": algo, "env": env, "split": split, "seed": seed, "mean_reward": value}
        for algo, env, split, seed, value in [
            ("sgfd_sac", "SGFD/MT-walker-walk-v0", "interpolation", 0, 500.0),
            ("sgfd_sac", "SGFD/MT-walker-walk-v0", "interpolation", 1, 600.0),
            ("sac", "SGFD/MT-walker-walk-v0", "interpolation", 0, 300.0),
            ("sgfd_sac", "SGFD/MT-cheetah-run-v0", "interpolation", 0, 100.0),
            ("sgfd_sac", "SGFD/walker-walk-v0", "test", 0, 900.0),
            ("sac", "SGFD/walker-walk-v0", "test", 0, 700.0),
        ]
    ]
    text = render_tables(rows)
    interpolation, test = text.index("# interpolation"), text.index("# test")
    assert test < interpolation  # backgrounds' unseen split first, then MT's
    lines = text[interpolation:].splitlines()
    assert [cell.strip() for cell in lines[1].strip("|").split("|")] == ["Task", "SGFD", "DR"]
    walker = next(line for line in lines if "MT-walker-walk" in line)
    assert "550.0 ± 50.0" in walker and "300.0 ± 0.0" in walker
    cheetah = next(line for line in lines if "MT-cheetah-run" in line)
    assert "100.0 ± 0.0" in cheetah and "–" in cheetah  # no DR run on cheetah
    total = next(line for line in lines if "Total" in line)
    assert "650.0" in total and "300.0" in total
    assert "over 1-2 seeds" in lines[0]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["train", "--env", "SGFD/walker-wallk-v0"], "did you mean SGFD/walker-walk-v0"),
        (["train", "--env", ENV_ID, *TINY, "-params", "clasifier_start:5"], "did you mean 'classifier_start'"),
        (["evaluate", "-f", "/nonexistent/logs"], "does not exist"),
        (["plot", "-f", "/nonexistent/logs"], "does not exist"),
        (["frobnicate"], "unknown command"),
        # a policy that cannot read the observations, named with the flags that fit
        (
            ["train", "--env", "SGFD/MT-cheetah-run-v0", "-n", "300", "--env-kwargs", "obs_type:'state'"],
            "augmentation_views), but the env gives state observations: use --quick",
        ),
        (
            [
                "train",
                "--algo",
                "sac",
                "--env",
                "SGFD/MT-cheetah-run-v0",
                "-n",
                "300",
                "--env-kwargs",
                "obs_type:'state'",
            ],
            "encodes images, but the env gives state observations: use --quick",
        ),
        (
            [
                "train",
                "--algo",
                "sac",
                "--env",
                "SGFD/MT-cheetah-run-v0",
                "-n",
                "300",
                "--env-kwargs",
                "obs_type:'state'",
                "-params",
                "policy:'MlpPolicy'",
            ],
            "takes no features_extractor_kwargs ({'features_dim': 50}): use --quick",
        ),
        (
            ["optimize", "--algo", "sac", "--env", ENV_ID, "--quick", "--env-kwargs", "obs_type:'pixels'"],
            "reads flat states, but the env gives pixel observations: use the paper-scale configuration",
        ),
        (["train", "--algo", "dbc", "--env", ENV_ID, "--quick", "-params", "augmentation_views:2"], "shifts images"),
        # values the zoo checks itself, before anything is built
        (["train", "--env", ENV_ID, *TINY, "-n", "0"], "-n must be >= 1, got 0"),
        (["train", "--env", ENV_ID, *TINY, "--seed", "-5"], "--seed -5: expected 0..4294967295, or -1 for a random"),
        (
            ["train", "--env", ENV_ID, *TINY, "-params", "learning_rate:'fast'"],
            "learning_rate must be a number, or a schedule 'lin_<start>' (linear from <start> to 0), got 'fast'",
        ),
        # the algorithms' own values, checked by sb3_sgfd (SAC's, SGFD's, the objectives') before anything is built
        (["train", "--env", ENV_ID, *TINY, "-params", "batch_size:0"], "batch_size must be a positive integer, got 0"),
        (["train", "--env", ENV_ID, *TINY, "-params", "buffer_size:-5"], "buffer_size must be a positive integer"),
        (["train", "--env", ENV_ID, *TINY, "-params", "tau:2"], "tau must be a number in "),
        (
            ["train", "--env", ENV_ID, *TINY, "-params", "reweight_ess_penalty:-1"],
            "reweight_ess_penalty must be a finite number >= 0, got -1",
        ),
        (["train", "--env", ENV_ID, *TINY, "-params", "learning_rate:-0.1"], "learning_rate must be a number > 0"),
        (["train", "--env", ENV_ID, *TINY, "-params", "n_envs:0"], "n_envs must be a positive integer, got 0"),
        (
            ["train", "--env", ENV_ID, "--quick", "-params", "n_timesteps:0"],
            "n_timesteps must be a positive integer, got 0",
        ),
        (["train", "--env", ENV_ID, *TINY, "--eval-episodes", "0"], "--eval-episodes must be >= 1, got 0"),
        # values rl-zoo3 would evaluate as Python: read first, each refusal naming the key
        (
            ["train", "--env", ENV_ID, *TINY, "--hyperparams", "learning_rate:1e-3x"],
            "-params learning_rate:1e-3x: not a Python value (invalid decimal literal); expected a number",
        ),
        (
            ["train", "--env", ENV_ID, *TINY, "--env-kwargs", "obs_type:pixels"],
            """--env-kwargs obs_type:pixels: pixels is not defined; a string needs quotes that reach Python, e.g. """
            '''--env-kwargs obs_type:"'pixels'"''',
        ),
        (
            ["train", "--env", ENV_ID, *TINY, "-params", "policy_kwargs:dict(activation_fn=nn.Relu)"],
            "-params policy_kwargs:dict(activation_fn=nn.Relu): nn.Relu is not defined",
        ),
        (
            ["train", "--env", ENV_ID, *TINY, "--eval-env-kwargs", "image_size"],
            "--eval-env-kwargs 'image_size': expected",
        ),
        (["optimize", "--env", ENV_ID, "--quick", "-params", "gamma:"], "-params gamma: no value after the colon"),
        (["enjoy", "--env", ENV_ID, "--env-kwargs", "split:test"], "--env-kwargs split:test: test is not defined"),
        # env settings: a typo named with what the id takes; what the zoo sets itself explained
        (
            ["train", "--env", ENV_ID, *TINY, "--env-kwargs", "obs_typ:'state'"],
            "does not take 'obs_typ' (did you mean 'obs_type'?); it takes ",
        ),
        (
            ["train", "--env", ENV_ID, *TINY, "--env-kwargs", "split:'extrapolation'"],
            "split:'extrapolation': the zoo sets split itself: it trains on 'train' and evaluates on every split",
        ),
        (["train", "--env", ENV_ID, *TINY, "--env-kwargs", "domain:2"], "the zoo gives each sub-env its own domain"),
        (
            ["train", "--env", ENV_ID, *TINY, "--eval-env-kwargs", "split:'train'"],
            "evaluation env_kwargs split:'train': the zoo sets split itself",
        ),
        # a log folder that cannot hold run folders (sysfs refuses every mkdir, to root too)
        (["train", "--env", ENV_ID, *TINY, "-f", "/sys/sgfd-zoo-logs"], "-f /sys/sgfd-zoo-logs: cannot"),
        (["train", "--env", ENV_ID, *TINY, "-f", __file__], f"-f {__file__}: is a file, not a folder"),
    ],
)
def test_bad_input_gives_one_clear_line_and_a_nonzero_exit(args, message, capsys, tmp_path):
    logs = tmp_path / "logs"
    if args[0] in ("train", "optimize") and "-f" not in args:
        args = [*args, "-f", str(logs)]  # where a run would go, if the check let one start
    assert zoo_main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("sgfd-zoo") and ": error: " in err[0] and message in err[0], err
    assert not logs.exists()


def test_the_forms_rl_zoo3_documents_pass_the_value_check_and_are_not_run():
    from sgfd_zoo.arguments import check_key_values

    given = ["policy_kwargs:dict(net_arch=[64, 64], activation_fn=nn.ReLU)", "train_freq:(1, 'step')"]
    given += ["learning_rate:'lin_1e-3'", "gamma:-1e-2", "normalize:True", "x:None", "y:{'a': [1, 2.5]}"]
    check_key_values("-params", given)
    # names are looked up, never called: a value that would run code when evaluated is still only read
    with pytest.raises(ZooError, match="not_a_name is not defined"):
        check_key_values("-params", ["x:print('ran')", "y:not_a_name"])


def test_train_help_is_one_usage_block_of_the_zoos_algorithms_and_loads_no_training_stack():
    code = "import sys; from sgfd_cli import main; main(['train', '--help']); "
    code += "print(sorted(m for m in ('torch', 'rl_zoo3', 'sgfd_envs', 'stable_baselines3') if m in sys.modules))"
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    seconds = time.perf_counter() - started
    lines = done.stdout.splitlines()
    assert lines[-1] == "[]" and done.stdout.count("usage: ") == 1, done.stdout
    assert seconds < 10, f"{seconds:.1f} s"  # no heavy import: a fraction of a second when the machine is idle
    assert "ppo" not in done.stdout and "--algo ALGO" in done.stdout
    assert all(algo in done.stdout for algo in SGFD_ALGOS)


def test_env_kwargs_on_the_command_line_are_merged_into_the_configurations(tmp_path):
    # The quick configuration of MT ids observes states with the morphology parameter; --env-kwargs changes one
    # setting and keeps the others (rl-zoo3 alone would replace them all: pixels, and a policy that cannot read them).
    manager = SGFDExperimentManager(
        Namespace(), "sac", ENV_ID, str(tmp_path), quick=True, env_kwargs={"observe_parameter": False}
    )
    hyperparams, saved = manager.read_hyperparameters()
    manager._preprocess_hyperparams(hyperparams)
    assert manager.env_kwargs == {"obs_type": "state", "observe_parameter": False}
    assert dict(saved)["env_kwargs"] == manager.env_kwargs == manager.eval_env_kwargs
    argv = ["--algo", "sac", "--env", ENV_ID, "--quick", "-f", str(tmp_path), "--env-kwargs", "image_size:64"]
    assert training.train(argv, check_only=True) == 0 and not list(tmp_path.iterdir())


def test_an_interval_longer_than_the_run_warns(tmp_path, capsys):
    argv = ["--algo", "sac", "--env", ENV_ID, "--quick", "-n", "500", "-f", str(tmp_path)]
    assert training.train([*argv, "--eval-freq", "1000", "--save-freq", "600"], check_only=True) == 0
    err = capsys.readouterr().err
    assert "warning: --eval-freq 1000 is more than the run's 500 steps: it is not evaluated during training" in err
    assert "warning: --save-freq 600 is more than the run's 500 steps: it has no periodic checkpoint" in err
    assert training.train(argv, check_only=True) == 0  # rl-zoo3's default --eval-freq (25000): not the user's doing
    assert "warning" not in capsys.readouterr().err


def test_unknown_algo_is_refused_by_the_parser_in_one_line(capsys):
    assert zoo_main(["train", "--algo", "ppo", "--env", ENV_ID]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("sgfd-zoo train: error: argument --algo: invalid choice: 'ppo'"), err


def test_zoo_error_reports_missing_checkpoint_for_resume(tmp_path):
    manager_args = (Namespace(), "sgfd_sac", ENV_ID, str(tmp_path))
    with pytest.raises(ZooError, match="no checkpoint"):
        SGFDExperimentManager(*manager_args, quick=True, resume=True)


# SAC and SGFD_SAC are killed and resumed in the bit-for-bit test below (AMBS resumes exactly in
# test_exact_resume.py); here two other objectives (SGQN's save and load: tests/agents/test_encoder_sac.py; its
# pixel run here took 4 minutes).
@pytest.mark.slow
@pytest.mark.parametrize("algo", ["dbc", "ted"])
def test_a_killed_run_resumes_from_its_last_checkpoint(algo, tmp_path):
    logs = tmp_path / "logs"
    params = ["-params", "learning_starts:200", "batch_size:32"]
    params += ["policy_kwargs:dict(net_arch=[32], features_extractor_kwargs=dict(features_dim=16))"]
    every = 200  # steps between checkpoints (evaluations: every other); the run is killed past 2, resumed to 4
    save = ["--save-freq", str(every), "--eval-freq", str(2 * every)]
    train_args = ["train", "--algo", algo, "--env", ENV_ID, "-f", str(logs), "--seed", "0", *TINY[:1]]
    train_args += ["--num-threads", "1", "--no-progress", "--verbose", "0", *params, "--eval-episodes", "1"]
    stalled = tmp_path / "stalled"
    # the run stops advancing past its second checkpoint (400), before its third (600), and is killed there
    launcher = [sys.executable, "-m", "tests.zoo.stalled_run", str(2 * every + every // 2), str(stalled)]
    process = subprocess.Popen(
        [*launcher, *train_args, "-n", "100000", *save], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
    )
    run = logs / algo / f"{RUN_NAME}_1"
    try:
        while not stalled.exists():
            assert process.poll() is None, process.stderr.read().decode()[-3000:]
            time.sleep(0.5)
    finally:
        os.kill(process.pid, signal.SIGKILL)
        process.wait()
    assert read_index(run)[0].num_timesteps == 2 * every
    newest = read_index(run)[0]
    assert not RunFolder(run).finished and not (run / f"{RUN_NAME}.zip").exists()
    assert newest.problem(run) is None and {"model", "replay_buffer"} <= set(newest.files)

    result = zoo(*train_args, "-n", str(4 * every), *save, "--resume")
    # The resumed model is the checkpoint's: a resume that restarted from step 0 would say "from 0 steps" (and
    # log to progress.csv, not progress_from_<steps>.csv).
    assert f"Resuming {run} from {newest.num_timesteps} steps" in result.stdout
    with (run / f"progress_from_{newest.num_timesteps}.csv").open() as handle:
        logged = [int(row["time/total_timesteps"]) for row in csv.DictReader(handle) if row["time/total_timesteps"]]
    assert logged and min(logged) > newest.num_timesteps
    assert not (logs / algo / f"{RUN_NAME}_2").exists(), "resume must continue the run, not start another"
    assert (run / f"{RUN_NAME}.zip").exists()
    model = RunFolder(run).load_model()
    assert model.num_timesteps == 4 * every and type(model) is SGFD_ALGOS[algo].algo_class
    # the objective's models came back from the checkpoint and trained on
    assert model.representation_model is not None and model.representation == algo
    with np.load(run / "evaluations_train.npz") as data:
        steps = data["timesteps"].tolist()
    # The evaluation before the kill is kept and the resumed run appends to it.
    assert steps == [2 * every, 4 * every]
    assert RunFolder(run).finished
    kept = sorted(path.name for path in run.glob("checkpoint_*_steps.zip"))
    expected = sorted(f"checkpoint_{n * every}_steps.zip" for n in (3, 4))
    assert kept == expected, "the two newest checkpoints are kept"
    # What trained it, a block per start: the resumed steps may come from other code.
    versions = RunFolder(run).versions_file.read_text()
    starts = [line.split(",")[0] for line in versions.splitlines() if line.startswith("=== ")]
    assert starts == ["=== from step 0", f"=== from step {newest.num_timesteps}"]
    assert versions.count(provenance.source()) == 2 and versions.count("stable-baselines3==") == 2


@pytest.mark.slow
# AMBS's own state across a save and a resume: tests/zoo/test_exact_resume.py (the suite's time, issue 38's CI)
@pytest.mark.parametrize("algo", ["sac", "sgfd_sac"])
def test_a_run_killed_and_resumed_ends_where_an_unbroken_run_ends_bit_for_bit(algo, tmp_path):
    # Checkpoints hold the training state (generators, envs): N steps, a kill, a resume to 2N, and the model
    # is that of 2N steps straight.
    params = [
        "-params",
        "learning_starts:200",
        "batch_size:32",
        *(["classifier_start:300"] if algo == "sgfd_sac" else []),
    ]
    params += [
        "policy_kwargs:dict(net_arch=[32], features_extractor_kwargs=dict(features_dim=8))"
        if algo == "ambs"
        else "policy_kwargs:dict(net_arch=[32])"
    ]
    common = ["train", "--algo", algo, "--env", ENV_ID, "--seed", "0", "--quick", "--num-threads", "1"]
    common += ["--no-progress", "--verbose", "0", "--eval-freq", "-1", "--save-freq", "400", *params]
    zoo(*common, "-f", str(tmp_path / "straight"), "-n", "800")
    broken = tmp_path / "broken"
    stalled = tmp_path / "stalled"
    # The broken run stops advancing at step 600 (past the checkpoint at 400, before the one at 800) and is killed
    # there: where the kill lands does not depend on the machine's speed.
    launcher = [sys.executable, "-m", "tests.zoo.stalled_run", "600", str(stalled)]
    process = subprocess.Popen(
        [*launcher, *common, "-f", str(broken), "-n", "100000"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    run = broken / algo / f"{RUN_NAME}_1"
    try:
        while not stalled.exists():
            assert process.poll() is None, process.stderr.read().decode()[-3000:]
            time.sleep(0.2)
    finally:
        os.kill(process.pid, signal.SIGKILL)
        process.wait()
    assert stalled.read_text() == "600"
    checkpoint = read_index(run)[0]
    assert checkpoint.num_timesteps == 400 and "training_state" in checkpoint.files
    result = zoo(*common, "-f", str(broken), "-n", "800", "--resume")
    assert f"from {checkpoint.num_timesteps} steps" in result.stdout and "not bit for bit" not in result.stderr
    straight = RunFolder(tmp_path / "straight" / algo / f"{RUN_NAME}_1").load_model()
    resumed = RunFolder(run).load_model()
    assert straight.num_timesteps == resumed.num_timesteps == 800
    for (key, expected), (_, got) in zip(
        straight.policy.state_dict().items(), resumed.policy.state_dict().items(), strict=True
    ):
        assert th.equal(expected, got), key


@pytest.mark.slow
def test_optimize_shares_a_study_through_a_journal_file(tmp_path):
    storage = tmp_path / "study.log"
    args = ["optimize", "--algo", "sgfd_sac", "--env", ENV_ID, "-f", str(tmp_path / "logs"), *TINY[:1]]
    args += ["-n", "400", "--num-threads", "1", "--no-progress", "--verbose", "0", "--n-evaluations", "1"]
    args += ["--eval-episodes", "1", "--storage", str(storage), "--study-name", "shared", "--n-startup-trials", "1"]
    args += ["-params", "learning_starts:100", "classifier_start:200"]
    for _ in range(2):  # two workers, one after the other, on the same study
        zoo(*args, "--n-trials", "1", "--sampler", "random", "--pruner", "none")
    import optuna

    study = optuna.load_study(
        study_name="shared",
        storage=optuna.storages.JournalStorage(optuna.storages.journal.JournalFileBackend(str(storage))),
    )
    complete = [trial for trial in study.trials if trial.state == optuna.trial.TrialState.COMPLETE]
    assert len(complete) == 2
    assert {"n_rff", "reweight_lr", "saliency_temperature", "accuracy_threshold"} <= set(complete[0].params)
    assert list((tmp_path / "logs" / "sgfd_sac").glob("report_*.csv"))


@pytest.mark.slow
@pytest.mark.ray
def test_the_quick_main_job_trains_both_evaluates_and_plots(tmp_path):
    # 1500 steps, the quick configuration's learning start at 1000: SGFD's classifier starts at 300 (a fifth), so that
    # SGFD trains as itself, not as plain SAC, for the run's last third
    record = tmp_path.parent / "quick.json"
    result = zoo("quick", "-f", str(tmp_path), "-n", "1500", "--eval-episodes", "1", "--record", str(record))
    assert "sweep: 4 trained, 0 already finished, 0 failed" in result.stdout  # two seeds by default
    # what it runs, said first; which figures are final and what it wrote (with sizes), said last
    assert result.stdout.startswith("quick: sgfd_sac and sac on SGFD/MT-walker-walk-v0, seeds 0 1, 1500 steps per run")
    assert "quick: SGFD's classifier starts at step 300 (the configuration's start moved" in result.stdout
    assert "quick: the tables above are the final figures: each run's final model evaluated on 1 episodes" in (
        result.stdout
    )
    assert re.search(r"quick: wrote [\d.]+ [kMG]?B into ", result.stdout)
    assert re.search(r"and its checkpoints \([\d.]+ [kMG]?B, of which replay buffers [\d.]+ [kMG]?B\)", result.stdout)
    # each run's log says the settings it used where the configuration's printed ones differ
    (sgfd_log,) = (tmp_path / "sgfd_sac").glob("*_1.log")
    assert "this run's settings where they differ from those above: classifier_start 300, n_timesteps 1500" in (
        sgfd_log.read_text()
    )
    saved = json.loads(record.read_text())
    assert saved["command"].startswith("sgfd-zoo quick -f ") and saved["settings"]["classifier_start"] == 300
    # SGFD's classifier trained and its weights acted; SAC's run has no classifier
    sgfd, sac = (RunFolder(tmp_path / algo / f"{RUN_NAME}_1") for algo in ("sgfd_sac", "sac"))
    assert sgfd.config["classifier_start"] == 300 and "classifier_start" not in sac.config
    _, accuracy = sgfd.log("sgfd/classifier_accuracy")
    _, ess = sgfd.log("sgfd/weight_ess")
    assert len(accuracy) > 0 and (ess < 1).any(), "SGFD's classifier trained and its weights acted"
    assert saved["results"] == (tmp_path / "results.md").read_text()
    assert saved["aggregate"] == (tmp_path / "aggregate.md").read_text()
    # Progress while it runs (a log: the block at the end), and no Ray noise.
    assert "0 running, 0 waiting, 4 finished, 0 failed" in result.stdout
    # each run's end, with its latest evaluation returns
    finished = [line for line in result.stdout.splitlines() if "] finished sgfd_sac on" in line]
    assert len(finished) == 2 and all(": last evaluation during training train " in line for line in finished)
    assert "Ray" not in result.stdout + result.stderr
    # The aggregate statistics over the two seeds, with intervals, and their figures.
    assert "# interpolation: normalised score" in result.stdout and "P(SGFD > algo)" in result.stdout
    assert (tmp_path / "aggregate.md").read_text() in result.stdout
    scores = read_results(tmp_path / "scores.csv")
    assert len(scores) == 2 * 2 * 3 and set(scores[0]) == {"algo", "env", "seed", "split", "return"}
    assert (tmp_path / "plots" / "aggregate_extrapolation.png").stat().st_size > 10_000
    rows = read_results(tmp_path / "results.csv")
    assert {(row["algo"], row["split"]) for row in rows} == {
        (algo, split) for algo in ("sgfd_sac", "sac") for split in ("train", "interpolation", "extrapolation")
    }
    returns = {(row["algo"], row["split"]): float(row["mean_reward"]) for row in rows}
    assert any(returns[("sgfd_sac", split)] != returns[("sac", split)] for split in ("train", "extrapolation"))
    assert (tmp_path / "results.md").read_text() in result.stdout
    assert (tmp_path / "plots" / f"{RUN_NAME}.png").stat().st_size > 10_000
    # A second call keeps what is finished.
    again = zoo("quick", "-f", str(tmp_path), "-n", "1500", "--eval-episodes", "1")
    assert "0 trained, 4 already finished" in again.stdout
    # The sweep numbers runs from 1 as rl-zoo3 does, so enjoy's default (newest run) finds the agent.
    watched = zoo(
        "enjoy",
        "--algo",
        "sgfd_sac",
        "--env",
        "SGFD/MT-walker-walk-v0",
        "-f",
        str(tmp_path),
        "-n",
        "200",
        "--no-render",
        "--env-kwargs",
        "split:'extrapolation'",
    )
    # the newest: seed 1's
    assert "Loading" in watched.stdout and "sgfd_sac/SGFD-MT-walker-walk-v0_2" in watched.stdout
    # Env kwargs that change the observations: one line, naming what to leave out.
    enjoy_args = ["enjoy", "--algo", "sac", "--env", ENV_ID, "-f", str(tmp_path), "-n", "10", "--no-render"]
    mismatch = zoo(*enjoy_args, "--env-kwargs", "observe_parameter:False", check=False)
    assert mismatch.returncode == 2, mismatch.stderr
    assert "does not give the observations the agent was trained on" in mismatch.stderr.strip().splitlines()[-1]
