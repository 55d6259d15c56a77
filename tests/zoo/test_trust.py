"""Folders other people wrote are data (docs/trust.md): each hostile file or value an audit tried is built here by
hand and given to the real command. Each is refused in one line naming the file and what was refused, with a
non-zero exit; its payload (a YAML tag, a spec's flag, a pickle that would create a marker file) does not run, and
the file a link points to (the victim) is unchanged."""

from __future__ import annotations

import csv
import hashlib
import json
import pickle
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

import sgfd_envs
from sgfd_zoo.runs import training_state
from sgfd_zoo.runs.checkpoints import Checkpoint, remove_checkpoint_files, write_index
from sgfd_zoo.runs.files import TMP_PREFIX, StoredFile, atomic_write
from sgfd_zoo.runs.folders import RunFolder, mark_finished
from sgfd_zoo.runs.records import RunRecord
from sgfd_zoo.runs.safe import DataLoader, redact
from tests.zoo.zoo_runs import ENV_ID, NAME, zoo

REPO = Path(__file__).resolve().parents[2]
SPLITS = ("train", "interpolation", "extrapolation")


def payload(marker: Path) -> str:
    """A YAML value that PyYAML's unsafe loader turns into ``open(marker, "w")``: it creates ``marker``."""
    return f'!!python/object/apply:builtins.open ["{marker}", "w"]'


class Opens:
    """Pickled, it unpickles as ``open(marker, "w")``: it creates ``marker``."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self) -> tuple:
        return (open, (str(self.marker), "w"))


def refused(argv: list[str], *named: str) -> str:
    """Run ``sgfd-zoo argv``; assert it exits non-zero with one line of stderr naming each of ``named``."""
    code, _out, err = zoo([str(arg) for arg in argv])
    assert code != 0 and len(err) == 1, err
    assert all(name in err[0] for name in named), err[0]
    return err[0]


def make_run(logs: Path, algo: str = "sac", run_id: int = 1, args: str = "seed: 0\n", config: str = "{}\n") -> Path:
    """A run folder by hand: rl-zoo3's args.yml and config.yml, nothing else."""
    run = logs / algo / f"{NAME}_{run_id}"
    (run / NAME).mkdir(parents=True)
    (run / NAME / "args.yml").write_text(args)
    (run / NAME / "config.yml").write_text(config)
    return run


def finish(run: Path, steps: int = 100) -> None:
    """Give ``run`` a final model (a zip that is no model: nothing here gets to load it) and its marker."""

    def write(tmp: str) -> None:
        with zipfile.ZipFile(tmp, "w") as archive:
            archive.writestr("data", "{}")

    mark_finished(run, atomic_write(run / f"{NAME}.zip", write), steps)


@pytest.fixture
def victim(tmp_path: Path) -> Path:
    """A file outside every folder the commands are given."""
    path = tmp_path / "elsewhere" / "victim.txt"
    path.parent.mkdir()
    path.write_text("precious\n")
    return path


# -- YAML ---------------------------------------------------------------------------------------------------


def test_every_committed_record_loads_as_with_pyyamls_unsafe_loader() -> None:
    files = sorted((REPO / "studies").rglob("*.yml"))
    assert len(files) > 100
    for path in files:  # our own committed files: safe to give the unsafe loader, to compare
        assert yaml.load(path.read_text(), Loader=DataLoader) == yaml.load(path.read_text(), Loader=yaml.UnsafeLoader)
    assert yaml.load("a: !!python/tuple [1, 2]", Loader=DataLoader) == {"a": (1, 2)}


def write_spec(study: Path, **changes: object) -> Path:
    spec = {"name": "s", "algos": ["sgfd_sac"], "envs": [ENV_ID], "seeds": [0], "train": ["--quick"], "n_episodes": 1}
    study.mkdir(parents=True, exist_ok=True)
    (study / "spec.yml").write_text(yaml.safe_dump({**spec, **changes}))
    return study / "spec.yml"


def write_record(study: Path, algo: str = "sgfd_sac", config: str = "{}\n") -> Path:
    """A whole record of seed 0 of ``algo``: its final evaluation on every split, its config, a logged step."""
    record = study / "runs" / algo / f"{NAME}_1"
    record.mkdir(parents=True)
    with (record / "final_evaluation.csv").open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["algo", "env", "split", "seed", "mean_reward", "std_reward", "n_episodes"])
        writer.writerows([algo, ENV_ID, split, 0, 10.0, 1.0, 1] for split in SPLITS)
    (record / "config.yml").write_text(config)
    (record / "diagnostics.csv").write_text("timesteps,sgfd/classifier_accuracy\n1000,0.5\n")
    return record


def hostile_yaml(tmp_path: Path, command: str, marker: Path) -> tuple[list[str], str]:
    """The folder an audit gave ``command``, with a payload in its YAML; the command line and the file named."""
    logs = tmp_path / "logs"
    hostile = f"seed: {payload(marker)}\naccuracy_threshold: {payload(marker)}\n"
    if command == "study":
        study = tmp_path / "studies" / "s"
        record = write_record(study, config=hostile)
        return ["study", write_spec(study), "-f", logs, "--export-only"], str(record / "config.yml")
    run = make_run(logs, "sgfd_sac", args=hostile, config=hostile)
    (run / "progress.csv").write_text("time/total_timesteps,sgfd/classifier_accuracy\n1000,0.5\n")
    argv = {
        "evaluate": ["evaluate", "-f", logs],  # listing the unfinished run
        "sweep": ["sweep", "--algos", "sgfd_sac", "--envs", ENV_ID, "--seeds", "0", "-f", logs, "-n", "0"],
        "classifier-accuracy": ["classifier-accuracy", "-f", logs],
    }[command]
    return argv, str(run / NAME)


@pytest.mark.parametrize("command", ["evaluate", "sweep", "classifier-accuracy", "study"])
def test_a_yaml_tag_naming_code_is_refused_and_never_built(tmp_path: Path, command: str) -> None:
    marker = tmp_path / "pwned"
    argv, where = hostile_yaml(tmp_path, command, marker)
    line = refused(argv, where, "refused: line ", "!!python/object/apply:builtins.open")
    assert ".yml" in line and not marker.exists()


# -- specs --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("train", "named"),
    [
        (["--quick", "--hyperparams", "x:__import__('builtins').open('{marker}', 'w')"], "--hyperparams x"),
        # a string rl-zoo3 would evaluate itself
        (["-params", "policy_kwargs:\"__import__('builtins').open('{marker}', 'w')\""], "-params policy_kwargs"),
        (["-params", "env_wrapper:'builtins.open'"], "-params env_wrapper names code"),
        (["-f", "{elsewhere}", "--address", "127.0.0.1:6379"], "-f (a folder); --address (a service)"),
        (["--conf-file", "{elsewhere}/hyperparams.py", "--gym-packages", "os"], "--conf-file (code or a model"),
        (["--storage", "postgresql://user:password@host/db"], "--storage (a service)"),
    ],
)
def test_a_spec_sets_only_per_run_flags_read_as_data(tmp_path: Path, train: list[str], named: str) -> None:
    marker, elsewhere = tmp_path / "pwned", tmp_path / "elsewhere"
    train = [flag.format(marker=marker, elsewhere=elsewhere) for flag in train]
    spec = write_spec(tmp_path / "studies" / "s", train=train)
    line = refused(["study", spec, "-f", tmp_path / "logs"], f"SPEC {spec}: train: refused {named}")
    assert "password" not in line or "--storage" in line
    assert not marker.exists() and not elsewhere.exists() and not (tmp_path / "logs").exists()


def test_the_committed_specs_flags_pass_as_they_are() -> None:
    from sgfd_zoo.study import read_spec

    for spec in sorted((REPO / "studies").glob("*/spec.yml")):
        flags = yaml.safe_load(spec.read_text())["train"]
        assert read_spec(spec)["train"] == [str(flag) for flag in flags]
    # rl-zoo3's dict(...) of literals among them
    mt_state = yaml.safe_load((REPO / "studies" / "mt-state" / "spec.yml").read_text())
    assert "policy_kwargs:dict(net_arch=[256, 256])" in mt_state["train"]


@pytest.mark.parametrize("name", ["../x", "{tmp}/x", "a/b", ".."])
def test_a_spec_name_is_a_plain_name(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, name: str) -> None:
    (tmp_path / "work").mkdir()
    monkeypatch.chdir(tmp_path / "work")  # the study's log folder is logs/studies/<name> from here
    spec = write_spec(tmp_path / "work" / "studies" / "s", name=name.format(tmp=tmp_path))
    refused(["study", spec, "--export-only"], "must be a plain name")
    assert sorted(path.name for path in tmp_path.iterdir()) == ["work"]
    assert not (tmp_path / "work" / "logs").exists()


# -- links --------------------------------------------------------------------------------------------------


def link_results(tmp_path: Path, victim: Path) -> tuple[list[str], Path]:
    logs = tmp_path / "logs"
    finish(make_run(logs))
    (logs / "results.md").symlink_to(victim)
    return ["evaluate", "-f", logs], logs / "results.md"


def link_final_evaluation(tmp_path: Path, victim: Path) -> tuple[list[str], Path]:
    logs = tmp_path / "logs"
    run = make_run(logs)
    finish(run)
    (run / "final_evaluation.json").symlink_to(victim)
    return ["evaluate", "-f", logs], run / "final_evaluation.json"


def link_plots(tmp_path: Path, victim: Path) -> tuple[list[str], Path]:
    logs = tmp_path / "logs"
    run = make_run(logs)
    np.savez(run / "evaluations_train.npz", timesteps=np.array([100]), results=np.ones((1, 2)))
    (logs / "plots").symlink_to(victim.parent)
    return ["plot", "-f", logs], logs / "plots"


def link_command(tmp_path: Path, victim: Path) -> tuple[list[str], Path]:
    study = tmp_path / "studies" / "s"
    write_record(study)
    (study / "command.txt").symlink_to(victim)  # committed as a link
    return ["study", write_spec(study), "-f", tmp_path / "logs", "--export-only"], study / "command.txt"


def link_sweep_log(tmp_path: Path, victim: Path) -> tuple[list[str], Path]:
    logs = tmp_path / "logs"
    (logs / "sac").mkdir(parents=True)
    (logs / "sac" / f"{NAME}_1.log").symlink_to(victim)
    return ["sweep", "--algos", "sac", "--envs", ENV_ID, "--seeds", "0", "-f", logs, "-n", "0"], logs / "sac"


def link_run_folder(tmp_path: Path, victim: Path) -> tuple[list[str], Path]:
    logs = tmp_path / "logs"
    (logs / "sac").mkdir(parents=True)
    (logs / "sac" / f"{NAME}_1").symlink_to(make_run(tmp_path / "other"), target_is_directory=True)
    return ["evaluate", "-f", logs], logs / "sac" / f"{NAME}_1"


@pytest.mark.parametrize(
    "hostile", [link_results, link_final_evaluation, link_plots, link_command, link_sweep_log, link_run_folder]
)
def test_no_write_follows_a_link(
    tmp_path: Path, victim: Path, hostile: Callable[[Path, Path], tuple[list[str], Path]]
) -> None:
    argv, link = hostile(tmp_path, victim)
    line = refused(argv, "symbolic link", str(link) if hostile is not link_sweep_log else f"{NAME}_1.log")
    assert "refused" in line
    assert victim.read_text() == "precious\n" and sorted(victim.parent.iterdir()) == [victim]


@pytest.mark.slow
def test_a_record_copies_no_link_no_secret_and_no_absolute_path(tmp_path: Path, victim: Path) -> None:
    from stable_baselines3 import SAC

    logs, study = tmp_path / "logs", tmp_path / "studies" / "s"
    spec = write_spec(study, algos=["sac"])
    url = "postgresql://user:hunter2@db.example/optuna"
    args = {"seed": 0, "log_folder": str(logs), "storage": url}  # as an earlier version wrote it
    run = make_run(logs, args=yaml.dump(args), config=yaml.safe_dump({"env_kwargs": {"obs_type": "state"}}))
    env = sgfd_envs.make_domain_vec_env(ENV_ID, obs_type="state")
    SAC("MlpPolicy", env, policy_kwargs={"net_arch": [8]}, buffer_size=10).save(run / f"{NAME}.zip")
    env.close()
    mark_finished(run, StoredFile(f"{NAME}.zip", (run / f"{NAME}.zip").stat().st_size), 100)
    (run / NAME / "versions.txt").symlink_to(victim)  # a secret, ready to be committed
    refused(["study", spec, "-f", logs, "--export-only"], str(run / NAME / "versions.txt"), "symbolic link")
    assert not (study / "runs").exists()

    (run / NAME / "versions.txt").unlink()
    (run / NAME / "versions.txt").write_text("source: git commit 0\n")
    for _ in range(2):  # exported again: the same record
        code, _out, err = zoo(["study", str(spec), "-f", str(logs), "--export-only"])
        assert code == 0, err
    record = RunRecord(study / "runs" / "sac" / f"{NAME}_1")
    assert [path.name for path in (study / "runs" / "sac").iterdir()] == [record.path.name]
    assert record.made_from(RunFolder(run)) and record.complete
    committed = "".join(path.read_text() for path in record.path.glob("*.*") if path.suffix in (".txt", ".yml"))
    assert "hunter2" not in committed and str(tmp_path) not in committed
    assert yaml.load((record.path / "args.yml").read_text(), Loader=DataLoader)["log_folder"] == "logs"


# -- resuming and indexes -----------------------------------------------------------------------------------


def stored(path: Path) -> StoredFile:
    return StoredFile(path.name, path.stat().st_size, hashlib.sha256(path.read_bytes()).hexdigest())


def train_again(logs: Path, *flags: str) -> list[str]:
    return ["train", "--algo", "sac", "--env", ENV_ID, "--quick", "-f", logs, "--seed", "0", *flags]


def test_a_crafted_training_state_is_refused_and_never_run(tmp_path: Path) -> None:
    marker, logs = tmp_path / "pwned", tmp_path / "logs"
    run = make_run(logs)
    model = run / "checkpoint_100_steps.zip"
    model.write_bytes(b"PK\x05\x06" + bytes(18))  # never reached: the state is read first
    state = run / "checkpoint_training_state_100_steps.pkl"  # an earlier version's pickle...
    state.write_bytes(pickle.dumps({"torch": Opens(marker)}))  # ...crafted, its size and sha256 in the index
    write_index(run, [Checkpoint(100, {"training_state": stored(state), "model": stored(model)})])
    line = refused(train_again(logs, "--run-id", "1", "--resume"), "does not load", "UnpicklingError: it names ")
    assert ".open, which a training state does not hold" in line and not marker.exists()


def test_a_training_state_is_data() -> None:
    legacy = REPO / "tests" / "data" / "legacy" / "0.1.0" / "train_folder" / "sgfd_sac" / f"{NAME}_1"
    path = legacy / "checkpoint_training_state_300_steps.pkl"
    state, unpickled = training_state.load(path), pickle.loads(path.read_bytes())  # our fixture: safe to unpickle
    assert same(state, unpickled)


def same(a: object, b: object) -> bool:
    """Equal to the last bit and of the same types: containers of arrays, tensors and numbers."""
    if type(a) is not type(b):
        return False
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(same(a[key], b[key]) for key in a)  # type: ignore[attr-defined]
    if isinstance(a, list | tuple):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))  # type: ignore[arg-type]
    if isinstance(a, np.ndarray | torch.Tensor):
        return a.dtype == b.dtype and np.array_equal(np.asarray(a), np.asarray(b))  # type: ignore[union-attr]
    return a == b or (a != a and b != b)  # NaN


def test_an_index_naming_a_file_outside_the_run_is_refused(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    run = make_run(logs)
    outside = tmp_path / "outside" / "checkpoint_training_state_100_steps.npz"
    outside.parent.mkdir()
    outside.write_bytes(b"not read")
    model = StoredFile(f"../../../outside/{outside.name}", 8, None)
    index = {"format": 2, "checkpoints": [{"num_timesteps": 100, "files": {"model": model.to_json()}}]}
    (run / "checkpoint.json").write_text(json.dumps(index))
    refused(train_again(logs, "--run-id", "1", "--resume"), f"{run / 'checkpoint.json'}: refused", "../../../outside")

    # finished.json naming another run's model: not a finished run of its own
    other = make_run(logs, run_id=2)
    finish(other)
    (run / "checkpoint.json").unlink()
    marker = json.loads((other / "finished.json").read_text())
    marker["model"]["name"] = f"../{other.name}/{NAME}.zip"
    (run / "finished.json").write_text(json.dumps(marker))
    refused(["evaluate", "-f", logs], f"{run / 'finished.json'}: refused")


def test_a_restart_deletes_nothing_through_a_link(tmp_path: Path, victim: Path) -> None:
    logs = tmp_path / "logs"
    run = make_run(logs)
    (victim.parent / f"{TMP_PREFIX}kept").write_text("kept\n")
    (run / "sub").symlink_to(victim.parent, target_is_directory=True)
    write_index(run, [Checkpoint(100, {"model": StoredFile("checkpoint_100_steps.zip", 1, None)})])  # unusable
    refused(train_again(logs, "--run-id", "1"), str(run / "sub"), "symbolic link")
    assert remove_checkpoint_files(run, []) == []  # and the cleanup itself does not descend into it
    assert (victim.parent / f"{TMP_PREFIX}kept").exists() and victim.read_text() == "precious\n"


# -- secrets and data files ---------------------------------------------------------------------------------


def test_credentials_in_urls_are_never_written(tmp_path: Path) -> None:
    url = "postgresql://user:hunter2@db.example:5432/optuna"
    run = RunFolder(tmp_path / "logs" / "sac" / f"{NAME}_1")
    argv = ["--algo", "sac", "--env", ENV_ID, "--storage", url, "--env-kwargs", "data_dir:'https://x.org/a?token=s3'"]
    run.record_start({"env_kwargs": {"obs_type": "state"}}, {"storage": url, "seed": 0}, argv, step=0)
    written = "".join(path.read_text() for path in run.config_dir.iterdir())
    assert "hunter2" not in written and "s3'" not in written and "postgresql://***@db.example:5432/optuna" in written
    assert run.args["storage"] == "postgresql://***@db.example:5432/optuna" and run.seed == 0
    assert (
        redact("see https://ghp_token@github.com/x and ftp://host/y") == "see https://***@github.com/x and ftp://host/y"
    )


@pytest.mark.parametrize("command", ["plot", "evaluate"])
def test_an_evaluations_file_of_python_objects_is_refused_in_one_line(tmp_path: Path, command: str) -> None:
    logs = tmp_path / "logs"
    run = make_run(logs)
    np.savez(run / "evaluations_train.npz", timesteps=np.array([1]), results=np.array([{"x": 1}], dtype=object))
    if command == "evaluate":  # its statistics read the evaluations of finished runs; its evaluation is kept
        finish(run)
        key = {"n_episodes": 1, "seed": 0, "model_mtime_ns": (run / f"{NAME}.zip").stat().st_mtime_ns}
        key["modes"] = [label for label, _ in sgfd_envs.evaluation_modes(ENV_ID)]
        rows = [{"algo": "sac", "env": ENV_ID, "split": label, "seed": 0, "mean_reward": 1.0, "std_reward": 0.0,
                 "n_episodes": 1, "stand_in": False} for label in key["modes"]]  # fmt: skip
        (run / "final_evaluation.json").write_text(json.dumps({"key": key, "rows": rows}))
    refused([command, "-f", logs, *(["--n-episodes", "1"] if command == "evaluate" else [])], "evaluations_train.npz")


def test_a_training_state_saved_as_data_comes_back_the_same(tmp_path: Path) -> None:
    from stable_baselines3 import SAC

    from sb3_sgfd import SGFD_SAC

    env = sgfd_envs.make_domain_vec_env(ENV_ID, obs_type="state", seed=1)
    for model in (SAC("MlpPolicy", env, learning_starts=10, buffer_size=100), SGFD_SAC("MlpPolicy", env)):
        model.learn(20)
        training_state.save(model, str(tmp_path / "state.npz"))
        assert same(training_state.load(tmp_path / "state.npz"), training_state.capture(model))
    env.close()
    with zipfile.ZipFile(tmp_path / "state.npz") as archive:  # arrays and JSON: nothing that unpickles
        assert all(name.endswith(".npy") for name in archive.namelist())
    np.savez(tmp_path / "objects.npz", allow_pickle=True, a0=np.array([Opens(tmp_path / "pwned")], dtype=object))
    with pytest.raises(ValueError, match="allow_pickle=False"):
        training_state.load(tmp_path / "objects.npz")
    assert not (tmp_path / "pwned").exists()


@pytest.mark.parametrize("hostile", ["payload", "normalize", "env_wrapper"])
def test_enjoy_reads_the_runs_saved_hyperparameters_as_data_before_rl_zoo3_does(tmp_path: Path, hostile: str) -> None:
    marker, logs = tmp_path / "pwned", tmp_path / "logs"
    config = {
        "payload": f"frame_stack: {payload(marker)}\n",
        # rl-zoo3's enjoy evaluates a normalize string, and imports an env_wrapper by its name
        "normalize": f"normalize: \"__import__('builtins').open('{marker}', 'w')\"\n",
        "env_wrapper": "env_wrapper: builtins.open\n",
    }[hostile]
    run = make_run(logs, config=config)
    finish(run)
    line = refused(["enjoy", "--algo", "sac", "--env", ENV_ID, "-f", logs, "--no-render"], f"{run / NAME}/config.yml")
    assert "refused" in line and not marker.exists()


@pytest.mark.parametrize(
    ("key", "value", "refused"),
    [
        ("policy", "sb3_sgfd.policies.MlpPolicy", False),  # the zoo's own runs name their classes so
        ("replay_buffer_class", "sb3_sgfd.buffers.DomainReplayBuffer", False),
        ("policy", "stable_baselines3.sac.policies.CnnPolicy", False),
        ("policy", "MlpPolicy", False),
        ("env_wrapper", [{"gymnasium.wrappers.TimeLimit": {"max_episode_steps": 10}}], False),
        ("policy", "os.system", True),
        ("policy", "sb3_sgfd_evil.policies.MlpPolicy", True),
        ("callback", "evil.Callback", True),
        ("env_wrapper", [{"evil.Wrapper": {}}], True),
    ],
)
def test_a_config_may_name_classes_of_the_installed_agents_and_envs_only(key: str, value, refused: bool) -> None:
    from sgfd_zoo.runs.safe import hyperparameter_problem

    assert (hyperparameter_problem(key, value) is not None) == refused
