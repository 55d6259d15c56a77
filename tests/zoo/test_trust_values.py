"""Nothing a spec, a record or a run folder holds names code or chooses a path (docs/trust.md): the audit's second
round, each case built here by hand and given to the real command. A spec naming code at any depth is refused before
anything runs; a record's values are checked before they become paths, cells or numbers; what is printed cannot
drive the terminal, what is written cannot drive a markdown renderer; and a folder swapped for a link while the
zoo writes takes no file out of it."""

from __future__ import annotations

import csv
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from sgfd_zoo.runs.bounded import RefusedFile, UnreadableFile
from sgfd_zoo.runs.files import write_below
from tests.zoo.test_trust import SPLITS, finish, make_run, refused, write_record, write_spec
from tests.zoo.zoo_runs import ENV_ID, NAME, zoo

# -- a spec names no code -----------------------------------------------------------------------------------

#: The audit's two reproductions: an allowed callable whose arguments name os.system, and an allowed class given a
#: path outside the log folder.
NESTED_CALL = (
    "callback:{'rl_zoo3.utils.get_callback_list': {'hyperparams': {'callback': [{'os.system': "
    "{'command': 'id > {marker}'}}]}}}"
)
TRUSTED_CLASS_AIMED_OUTSIDE = (
    "callback:{'stable_baselines3.common.callbacks.CheckpointCallback': {'save_path': '{outside}', 'save_freq': 1}}"
)


@pytest.mark.parametrize(
    ("setting", "named"),
    [
        (["-params", NESTED_CALL], "-params callback names code to import"),
        (["-params", TRUSTED_CLASS_AIMED_OUTSIDE], "-params callback names code to import"),
        (["--hyperparams", "policy:'sb3_sgfd.policies.MlpPolicy'"], "a policy by its registered short name only"),
        (["-params", "policy_kwargs:dict(features_extractor_class='os.system')"], "names code ('os.system')"),
        (
            ["-params", "policy_kwargs:dict(net_arch=[8], optimizer_kwargs=dict(hooks=[{'x': 'os.system'}]))"],
            "-params policy_kwargs names code ('os.system')",
        ),
        (
            ["-params", "policy_kwargs:dict(optimizer_kwargs=dict(files=['{outside}/x']))"],
            "-params policy_kwargs gives a path",
        ),
        (["--env-kwargs", "obs_type:{'os.system': 1}"], "--env-kwargs obs_type names code ('os.system')"),
        (["--env-kwargs", "background_dir:'{outside}'"], "--env-kwargs background_dir gives a path"),
        (["--eval-env-kwargs", "data_dir:'~/data'"], "--eval-env-kwargs data_dir gives a path ('~/data')"),
    ],
    ids=[
        "audit-nested-os-system-callback-refused-outright",
        "audit-checkpoint-callback-outside-refused-outright",
        "policy-path",
        "class-in-kwargs",
        "code-four-levels-deep",
        "path-three-levels-deep",
        "dotted-key",
        "path",
        "home-path",
    ],
)
@pytest.mark.parametrize("plan", [False, True])
def test_a_spec_names_no_code_and_no_path_at_any_depth(
    tmp_path: Path, setting: list[str], named: str, plan: bool
) -> None:
    marker, outside = tmp_path / "pwned", tmp_path / "outside"
    flags = ["--quick", *(item.replace("{marker}", str(marker)).replace("{outside}", str(outside)) for item in setting)]
    spec = write_spec(tmp_path / "studies" / "s", train=flags)
    logs = tmp_path / "logs"
    refused(["study", spec, "-f", logs, *(["--plan"] if plan else [])], f"SPEC {spec}: train: refused", named)
    assert not marker.exists() and not outside.exists() and not logs.exists()


def test_a_spec_names_its_policy_by_its_short_name(tmp_path: Path) -> None:
    from sgfd_zoo.study import read_spec

    flags = ["--quick", "-params", "policy:'MlpPolicy'", "policy_kwargs:dict(net_arch=[8])", "--env-kwargs",
             "obs_type:'state'"]  # fmt: skip
    assert read_spec(write_spec(tmp_path / "s", train=flags))["train"] == flags


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("callback", {"rl_zoo3.utils.get_callback_list": {"hyperparams": {"callback": [{"os.system": {}}]}}}),
        ("callback", [{"stable_baselines3.common.callbacks.CheckpointCallback": {"save_path": "/tmp/elsewhere"}}]),
        ("env_wrapper", [{"gymnasium.wrappers.TimeLimit": {"max_episode_steps": "evil.module"}}]),
        ("policy_kwargs", "dict(features_extractor_class='os.system')"),
    ],
)
def test_a_run_configs_code_hyperparameters_are_read_at_every_depth(key: str, value: object) -> None:
    from sgfd_zoo.runs.safe import hyperparameter_problem

    assert hyperparameter_problem(key, value) is not None


@pytest.mark.parametrize(
    ("changes", "named"),
    [
        ({"algos": [["sgfd_sac"]]}, "algos must be a list of algorithm keys"),
        ({"seeds": [True]}, "seeds must be a list of integers >= 0"),
        ({"train": [{"-f": "/x"}]}, "train must be a list of flags and values"),
        ({"n_episodes": [1]}, "n_episodes must be an integer >= 1"),
        ({"reference": "sac"}, "reference 'sac' is not one of its algos"),
    ],
)
def test_a_spec_value_of_the_wrong_type_is_one_line(tmp_path: Path, changes: dict, named: str) -> None:
    refused(["study", write_spec(tmp_path / "studies" / "s", **changes), "--plan"], named)


# -- a record's values are data -----------------------------------------------------------------------------


def rewrite_rows(record: Path, change: dict[str, str], split: str = "train") -> None:
    """Change the fields ``change`` of ``record``'s row of ``split``."""
    with (record / "final_evaluation.csv").open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    for row in rows:
        row.update(change if row["split"] == split else {})
    with (record / "final_evaluation.csv").open("w", newline="") as handle:
        writer = csv.DictWriter(handle, list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def test_a_records_split_cannot_climb_out_of_the_study(tmp_path: Path) -> None:
    study, outside = tmp_path / "studies" / "s", tmp_path / "outside"
    outside.mkdir()
    record = write_record(study)
    (study / "plots" / "aggregate_x").mkdir(parents=True)  # committed, empty
    with (record / "final_evaluation.csv").open("a", newline="") as handle:  # the audit's extra row
        climb = f"x/../../{os.path.relpath(outside, study)}/owned"
        csv.writer(handle).writerow(["sgfd_sac", ENV_ID, climb, 0, 10.0, 1.0, 1])
    refused(["study", write_spec(study), "-f", tmp_path / "logs", "--export-only"], f"split {climb!r} is not one of")
    assert list(outside.iterdir()) == [] and not (study / "results.md").exists()


@pytest.mark.parametrize(
    ("change", "named"),
    [
        ({"env": "SGFD/MT-cheetah-run-v0"}, "a row names env 'SGFD/MT-cheetah-run-v0', its run's is"),
        ({"algo": "sac"}, "a row names algo 'sac', its run's is 'sgfd_sac'"),
        ({"algo": "<img src=x onerror=alert(1)>"}, "is not an algorithm's key"),
        ({"seed": "zero"}, "seed 'zero' is not a whole number"),
        ({"seed": "1"}, "the rows of seeds [0, 1], not one run's"),
        ({"mean_reward": "nan"}, "mean_reward 'nan' is not a finite number"),
        ({"mean_reward": "inf"}, "mean_reward 'inf' is not a finite number"),
        ({"std_reward": "-1"}, "std_reward '-1' is not a finite number >= 0"),
        ({"n_episodes": "0"}, "n_episodes '0' is not a whole number >= 1"),
        ({"split": "\x1b]0;owned\x07"}, "split '\\x1b]0;owned\\x07' is not one of"),
    ],
)
def test_a_records_fields_are_checked_before_they_are_used(tmp_path: Path, change: dict, named: str) -> None:
    study = tmp_path / "studies" / "s"
    record = write_record(study)
    rewrite_rows(record, change)
    line = refused(["study", write_spec(study), "-f", tmp_path / "logs", "--export-only"], str(record), named)
    assert "\x1b" not in line and "\x07" not in line
    assert not (study / "results.md").exists()


@pytest.mark.parametrize(
    ("file", "text", "named"),
    [
        ("diagnostics.csv", "timesteps,sgfd/classifier_accuracy\n6e3,0.5\n", "timesteps '6e3' is not a whole number"),
        ("diagnostics.csv", "timesteps,sgfd/classifier_accuracy\n1000,nan\n", "'nan' is not a finite number"),
        ("config.yml", "accuracy_threshold: [1]\n", "accuracy_threshold is unreadable (the value [1] is not a finite"),
        ("config.yml", "accuracy_threshold: 3\n", "(3 is not a fraction in [0, 1])"),
        ("config.yml", "reading: [x]\n", "reading is unreadable (['x'] is not a string)"),
    ],
)
def test_a_records_logs_and_config_are_checked_before_they_are_used(
    tmp_path: Path, file: str, text: str, named: str
) -> None:
    study = tmp_path / "studies" / "s"
    record = write_record(study)
    (record / file).write_text(text)
    refused(["study", write_spec(study), "-f", tmp_path / "logs", "--export-only"], str(record / file), named)
    assert not (study / "results.md").exists()


def test_an_evaluations_file_with_a_return_that_is_not_finite_is_refused(tmp_path: Path) -> None:
    study = tmp_path / "studies" / "s"
    record = write_record(study)
    np.savez(record / "evaluations_train.npz", timesteps=np.array([100]), results=np.array([[1.0, np.inf]]))
    refused(["study", write_spec(study), "-f", tmp_path / "logs", "--export-only"], "not a finite return")


def test_a_fresh_evaluations_return_that_is_not_finite_is_refused() -> None:
    from sgfd_zoo.report.statistics import score_rows

    row = {"algo": "sac", "env": ENV_ID, "seed": 0, "split": "train", "mean_reward": float("nan"), "run": "r"}
    with pytest.raises(UnreadableFile, match="r is unreadable \\(train mean_reward nan is not a finite number"):
        score_rows([row])


# -- printed and written safely -----------------------------------------------------------------------------


def test_a_run_folders_algorithm_becomes_no_cell_and_no_terminal_escape(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    for algo in ("<img src=x onerror=alert(1)>", "\x1b]0;owned\x07sac"):
        shutil.rmtree(logs, ignore_errors=True)
        finish(make_run(logs, algo=algo))
        line = refused(["evaluate", "-f", logs], "is not an algorithm's key")
        assert "\x1b" not in line and "\x07" not in line
        assert not (logs / "results.md").exists()


def test_the_tables_show_names_as_text() -> None:
    from sgfd_zoo.report.evaluate import render_tables
    from sgfd_zoo.report.markdown import markdown_text

    hostile = "<img src=x onerror=alert(1)> [x](javascript:alert(1)) a|b \x1b[2J"
    escaped = markdown_text(hostile)
    assert escaped == "\\<img src=x onerror=alert(1)\\> \\[x\\](javascript:alert(1)) a\\|b \\\\x1b\\[2J"
    rows = [{"algo": hostile, "env": ENV_ID, "split": split, "seed": 0, "mean_reward": 1.0} for split in SPLITS]
    table = render_tables(rows)
    unescaped = re.compile(r"(?<!\\)(<img|\]\(javascript)")  # a tag, a link: each markup character escaped
    assert not unescaped.search(table) and "\x1b" not in table


def unfinished_run(logs: Path, command: str) -> Path:
    run = make_run(logs, args=yaml.safe_dump({"seed": 3}))
    (run / NAME / "command.txt").write_text(command)
    return run


def test_evaluates_continue_command_is_rebuilt_from_checked_fields(tmp_path: Path) -> None:
    logs, marker = tmp_path / "logs", tmp_path / "pwned"
    finish(make_run(logs, run_id=9))  # a finished run, so that evaluate goes on
    unfinished_run(logs, f"sgfd-zoo train --algo sac --env {ENV_ID} --seed 3 -f /elsewhere --quick -n 500\n")
    _code, out, _ = zoo(["evaluate", "-f", str(logs), "--n-episodes", "1"])
    line = next(line for line in out.splitlines() if "seed 3" in line)
    assert line.endswith(f"sgfd-zoo train --algo sac --env {ENV_ID} --seed 3 -f {logs} --quick -n 500 --run-id 1")

    shutil.rmtree(logs / "sac" / f"{NAME}_1")
    hostile = f"-params \"callback:{{'os.system': {{'command': 'touch {marker}'}}}}\" \x1b]0;owned\x07"
    unfinished_run(logs, f"sgfd-zoo train --algo sac --env {ENV_ID} --seed 3 {hostile}\n")
    _code, out, _ = zoo(["evaluate", "-f", str(logs), "--n-episodes", "1"])
    line = next(line for line in out.splitlines() if "seed 3" in line)
    assert line.endswith("the command that trained it, with --run-id 1") and "os.system" not in out
    assert "\x1b" not in out and not marker.exists()


def test_a_folder_swapped_for_a_link_while_plot_writes_takes_no_file_out(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from matplotlib.figure import Figure

    logs, outside = tmp_path / "logs", tmp_path / "outside"
    outside.mkdir()
    run = make_run(logs)
    np.savez(run / "evaluations_train.npz", timesteps=np.array([100, 200]), results=np.ones((2, 2)))
    (logs / "plots").mkdir()
    real_savefig = Figure.savefig

    def swap_then_save(figure: Figure, target: object, **kwargs: object) -> None:
        # the audit's race, at the worst moment: the folder checked, the temporary file not yet written
        if not (logs / "plots").is_symlink():
            (logs / "plots").rename(logs / "plots.before")
            (logs / "plots").symlink_to(outside, target_is_directory=True)
        real_savefig(figure, target, **kwargs)

    monkeypatch.setattr(Figure, "savefig", swap_then_save)
    code, _out, err = zoo(["plot", "-f", str(logs)])
    assert list(outside.iterdir()) == []  # not the figure, not its temporary file
    assert code == 0, err
    assert [path.name for path in (logs / "plots.before").iterdir()] == [f"{NAME}.png"]


def test_a_write_through_a_linked_folder_is_refused_even_unchecked(tmp_path: Path) -> None:
    root, outside = tmp_path / "root", tmp_path / "outside"
    root.mkdir()
    outside.mkdir()
    (root / "linked").symlink_to(outside, target_is_directory=True)
    with pytest.raises(RefusedFile, match="a symbolic link"):
        write_below(root, root / "linked" / "file.txt", lambda tmp: Path(tmp).write_text("x"))
    with pytest.raises(RefusedFile, match="not inside"):
        write_below(root, outside / "file.txt", lambda tmp: Path(tmp).write_text("x"))
    assert list(outside.iterdir()) == []
    (root / "sub").mkdir()
    assert write_below(root, root / "sub" / "file.txt", lambda tmp: Path(tmp).write_text("x")).size == 1
    assert [path.name for path in (root / "sub").iterdir()] == ["file.txt"]  # no temporary folder left
