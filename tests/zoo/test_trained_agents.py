"""What a researcher does with a trained run: watch it (enjoy, with its saved settings read as data only), record
a video on any split and domain, push it to the Hugging Face Hub and load it back (without the network: a dry run
and a local copy), and draw rl-zoo3's own plots of its folder."""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml

import sgfd_envs
from sgfd_cli import main as zoo_main
from sgfd_zoo.runs.folders import RunFolder, read_yaml

# Every test here takes a run trained for the module (about 15 s a worker): not the edit loop's.
pytestmark = pytest.mark.slow

ENV_ID = "SGFD/MT-walker-walk-v0"
NAME = "SGFD-MT-walker-walk-v0"
# 2000 steps of 4 sub-envs: each finishes one 500-step episode (its monitor file has a row); two evaluations of two
# episodes (rl-zoo3's all_plots needs more than one).
TRAIN = ["train", "--algo", "sac", "--env", ENV_ID, "--quick", "-n", "2000", "--seed", "0", "--eval-freq", "1000"]
TRAIN += ["--eval-episodes", "2", "--num-threads", "1", "--no-progress", "--verbose", "0"]
TRAIN += ["-params", "learning_starts:1500", "batch_size:16", "buffer_size:2500", "policy_kwargs:dict(net_arch=[16])"]


def zoo(args: list[str]) -> tuple[int, str, list[str]]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = zoo_main(args)
    return code, out.getvalue(), [line for line in err.getvalue().splitlines() if line.strip()]


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A log folder with one finished tiny SAC run (state observations), trained through sgfd-zoo train."""
    folder = tmp_path_factory.mktemp("trained") / "logs"
    code, _, err = zoo([*TRAIN, "-f", str(folder)])
    assert code == 0, err
    return folder


@pytest.fixture
def copied(logs: Path, tmp_path: Path) -> Path:
    """A copy of the trained log folder, for a test that changes it."""
    return Path(shutil.copytree(logs, tmp_path / "logs"))


def watch(folder: Path, *extra: str) -> tuple[int, str, list[str]]:
    return zoo(["enjoy", "--algo", "sac", "--env", ENV_ID, "-f", str(folder), "-n", "10", *extra])


# -- enjoy reads the run's settings as data: rl-zoo3's unsafe loader never sees them ---------------------------

HOSTILE_STARTS = {
    "an OrderedDict of nothing": "x: !!python/object/apply:collections.OrderedDict []\n",
    "its mapping form": "x: !!python/object/apply:collections.OrderedDict {}\n",
    "a tuple pair": "x: !!python/object/apply:collections.OrderedDict [[!!python/tuple [a, 1]]]\n",
}


@pytest.mark.parametrize("start", list(HOSTILE_STARTS))
@pytest.mark.parametrize("file", ["config.yml", "args.yml"])
def test_enjoy_refuses_a_saved_file_it_cannot_read_as_data_and_runs_nothing(
    copied: Path, file: str, start: str
) -> None:
    # A value the zoo's data loader cannot build but PyYAML's unsafe loader can, then a tag that runs a command, then
    # the file's own settings (as a plain mapping: a document rl-zoo3's loader reads whole; the zoo before version
    # 0.2.0 skipped such a file and rl-zoo3 ran the command).
    marker = copied.parent / "pwned"
    saved = RunFolder.at(copied, "sac", ENV_ID, 1).config_dir / file
    command = f"y: !!python/object/apply:os.system ['touch {marker}']\n"
    saved.write_text(HOSTILE_STARTS[start] + command + yaml.dump(dict(read_yaml(saved)[0])))
    assert set(yaml.load(saved.read_text(), Loader=yaml.UnsafeLoader)) > {"x", "y"} and marker.exists()  # it runs
    marker.unlink()
    code, out, err = watch(copied, "--no-render")
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith("sgfd-zoo enjoy: error: ") and "refused" in err[0] and str(saved) in err[0], err
    assert not marker.exists() and "Episode" not in out


def test_enjoy_hands_rl_zoo3_the_env_settings_it_read_and_plays_the_split_asked_for(logs: Path) -> None:
    code, out, err = watch(logs, "--no-render", "-n", "500", "--split", "extrapolation", "--seed", "3")
    assert code == 0, err
    assert f"Loading {logs}/sac/{NAME}_1/{NAME}.zip" in out
    # the run's settings, its recorded family among them, and the split asked for
    played = (
        "env settings {'robots': 'hipbmdp', 'obs_type': 'state', 'observe_parameter': True, 'split': 'extrapolation'}"
    )
    assert "1 Episodes" in out and played in out, out
    code, _, err = watch(logs, "--no-render", "--split", "extrapolation", "--env-kwargs", "split:'train'")
    assert code == 2 and "--split extrapolation and --env-kwargs split:'train' disagree" in err[-1]


def test_enjoy_without_a_display_says_in_one_line_what_to_use(logs: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    for variable in ("DISPLAY", "WAYLAND_DISPLAY", "SDL_VIDEODRIVER"):
        monkeypatch.delenv(variable, raising=False)
    code, out, err = watch(logs)
    assert code == 2 and len(err) == 1 and "Loading" not in out
    assert err[0].startswith("sgfd-zoo enjoy: error: no display to show the agent on (DISPLAY is unset): add ")
    assert "--no-render" in err[0] and "sgfd-zoo record-video" in err[0]


def test_the_ids_render_for_humans_in_a_window_and_enjoy_shows_one(logs: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")  # SDL's window without a screen: pygame draws it all the same
    import pygame

    env = gym.make("SGFD/walker-walk-v0", split="train", domain=1, render_mode="human", image_size=64)
    assert isinstance(env.unwrapped, gym.Env) and env.render_mode == "human"
    env.reset(seed=0)
    env.step(env.action_space.sample())
    window = pygame.display.get_surface()
    assert window is not None and window.get_size() == (64, 64)
    shown = pygame.surfarray.array3d(window).swapaxes(0, 1)  # what the window holds: the env's own frame
    frame = env.unwrapped.render()
    assert frame is not None and np.array_equal(shown, frame)
    env.close()
    code, out, err = watch(logs, "-n", "5")
    assert code == 0, err
    assert "Loading" in out


# -- videos ----------------------------------------------------------------------------------------------


def frames_of(path: Path) -> list[np.ndarray]:
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    width, height = next(reader)["size"]
    return [np.frombuffer(frame, np.uint8).reshape(height, width, 3) for frame in reader]


def first_frame(split: str, domain: int, seed: int) -> np.ndarray:
    """The frame the env of ``split``/``domain`` shows after its reset with ``seed``, scaled by 4 as the video."""
    env = gym.make(
        ENV_ID, split=split, domain=domain, obs_type="state", observe_parameter=True, render_mode="rgb_array"
    )
    env.reset(seed=seed)
    frame = env.render()
    env.close()
    assert frame is not None
    return np.repeat(np.repeat(frame, 4, axis=0), 4, axis=1).astype(float)


@pytest.mark.parametrize(("split", "domain"), [("train", 2), ("extrapolation", 0)])
def test_record_video_writes_an_mp4_of_the_split_and_domain_asked_for(logs: Path, split: str, domain: int) -> None:
    args = ["record-video", "--algo", "sac", "--env", ENV_ID, "-f", str(logs), "-n", "20", "--seed", "4"]
    code, out, err = zoo([*args, "--split", split, "--domain", str(domain)])
    assert code == 0, err
    path = (
        logs / "sac" / f"{NAME}_1" / "videos" / f"final-model-sac-{NAME}-{split}-domain{domain}-step-0-to-step-20.mp4"
    )
    assert out.strip().endswith(f"Saved {path}")
    frames = frames_of(path)
    assert len(frames) == 21 and frames[0].shape == (336, 336, 3)
    # H.264 is lossy: the first frame is far closer to its own domain's than to the other split's
    other = ("extrapolation", 0) if split == "train" else ("train", 2)
    error = np.abs(frames[0] - first_frame(split, domain, 4)).mean()
    assert error < np.abs(frames[0] - first_frame(*other, 4)).mean() / 2, error


# -- the Hugging Face Hub, without the network -------------------------------------------------------------

HUB_FILES = ["README.md", "args.yml", "config.yml", "env_kwargs.yml", "replay.mp4", "results.json"]
HUB_FILES += [f"sac-{NAME}.zip", "train_eval_metrics.zip"]


@pytest.fixture(scope="module")
def pushed(logs: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """What push-to-hub would push of the trained run, written by its dry run."""
    folder = tmp_path_factory.mktemp("hub") / "repository"
    args = ["push-to-hub", "--algo", "sac", "--env", ENV_ID, "-f", str(logs), "-orga", "lab", "--n-episodes", "1"]
    code, out, err = zoo([*args, "-n", "10", "--dry-run", str(folder)])
    assert code == 0, err
    assert out.strip().endswith(f"8 files for lab/sac-{NAME} in {folder}: {', '.join(sorted(HUB_FILES))}")
    return folder


def test_a_dry_run_writes_exactly_what_would_be_pushed(pushed: Path, logs: Path) -> None:
    from huggingface_hub import ModelCard

    run = RunFolder.at(logs, "sac", ENV_ID, 1)
    assert sorted(path.name for path in pushed.iterdir()) == sorted(HUB_FILES)
    assert (pushed / f"sac-{NAME}.zip").read_bytes() == run.model_path.read_bytes()
    # the settings it trained with, its family among them, as evaluate plays it
    trained_on = {"obs_type": "state", "observe_parameter": True, "robots": "hipbmdp"}
    assert yaml.safe_load((pushed / "env_kwargs.yml").read_text()) == trained_on == run.env_kwargs
    assert yaml.safe_load((pushed / "args.yml").read_text())["log_folder"] == "logs"  # the folder's name only
    with zipfile.ZipFile(pushed / "train_eval_metrics.zip") as archive:
        metrics = set(archive.namelist())
    assert {"evaluations.npz", "evaluations_train.npz", "0.monitor.csv", "progress.csv"} <= metrics
    # Every split's evaluation, with its domains, in results.json, the card's text and its metadata.
    results = json.loads((pushed / "results.json").read_text())["splits"]
    assert list(results) == [label for label, _ in sgfd_envs.evaluation_modes(ENV_ID)]
    assert results["extrapolation"]["domains"] == "1 domain: setting 10 of 1-10"
    assert results["train"]["domains"] == "4 domains: settings 2, 3, 5, 6 of 1-10"  # the authors' split
    card = ModelCard.load(pushed / "README.md")
    assert card.data.library_name == "stable-baselines3" and ENV_ID in card.data.tags
    evals = card.data.eval_results
    assert [result.dataset_split for result in evals] == list(results)
    for result in evals:
        mean, std = results[result.dataset_split]["mean_reward"], results[result.dataset_split]["std_reward"]
        assert result.metric_value == f"{mean:.2f} +/- {std:.2f}" and result.dataset_type == ENV_ID
        assert f"| {result.dataset_split} | {results[result.dataset_split]['domains']} |" in card.text
    assert len(frames_of(pushed / "replay.mp4")) == 11


def test_push_to_hub_refuses_in_one_line_what_would_go_wrong(logs: Path, tmp_path: Path) -> None:
    args = ["push-to-hub", "--algo", "sac", "--env", ENV_ID, "-f", str(logs), "--n-episodes", "1"]
    code, _, err = zoo(args)
    assert code == 2 and err == [
        "sgfd-zoo push-to-hub: error: -orga is required (the Hub user or organization), unless --dry-run FOLDER "
        "writes the files only"
    ]
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "mine.txt").write_text("x")
    code, _, err = zoo([*args, "--dry-run", str(tmp_path / "full")])
    assert code == 2 and len(err) == 1 and "expected a new or empty folder" in err[0]
    assert [path.name for path in (tmp_path / "full").iterdir()] == ["mine.txt"]


def test_a_local_copy_loads_into_a_finished_run_that_enjoy_and_evaluate_take(pushed: Path, tmp_path: Path) -> None:
    folder = tmp_path / "logs"
    args = ["load-from-hub", "--algo", "sac", "--env", ENV_ID, "-f", str(folder)]
    code, out, err = zoo([*args, "--from-dir", str(pushed)])
    assert code == 0, err
    run = RunFolder.at(folder, "sac", ENV_ID, 1)
    assert f"Saved to {run.path}" in out and run.finished
    assert run.model_path.read_bytes() == (pushed / f"sac-{NAME}.zip").read_bytes()
    # the settings it trained with, its family among them (recorded by the run: sgfd_envs.families)
    assert run.env_kwargs == {"obs_type": "state", "observe_parameter": True, "robots": "hipbmdp"}
    assert run.evaluations("train") is not None
    code, out, err = watch(folder, "--no-render", "-n", "500")
    assert code == 0 and "1 Episodes" in out, err
    code, out, err = zoo(["evaluate", "-f", str(folder), "--n-episodes", "1"])
    assert code == 0 and "extrapolation" in out, err


def test_a_copy_with_a_hostile_file_is_refused_before_anything_is_copied(pushed: Path, tmp_path: Path) -> None:
    copy = Path(shutil.copytree(pushed, tmp_path / "copy"))
    marker = tmp_path / "pwned"
    (copy / "env_kwargs.yml").write_text(f"x: !!python/object/apply:os.system ['touch {marker}']\n")
    folder = tmp_path / "logs"
    code, _, err = zoo(["load-from-hub", "--algo", "sac", "--env", ENV_ID, "-f", str(folder), "--from-dir", str(copy)])
    assert code == 2 and len(err) == 1 and "!!python/object/apply:os.system" in err[0], err
    assert not marker.exists() and not folder.exists()


# -- rl-zoo3's own plots on the zoo's run folders -----------------------------------------------------------


def rl_zoo3_plot(script: str, *args: str) -> subprocess.CompletedProcess:
    """rl-zoo3's plotting script ``script`` on ``args``, in a Python of its own, with matplotlib drawing off screen;
    what it drew is printed after it: each curve's number of points."""
    code = (
        f"import sys; sys.argv = ['{script}', *{list(args)!r}]\n"
        f"from rl_zoo3.plots.{script} import {script}\n"
        f"{script}()\n"
        "import matplotlib.pyplot as plt\n"
        "print('points', [len(line.get_xdata()) for n in plt.get_fignums() for ax in plt.figure(n).axes "
        "for line in ax.get_lines()])\n"
    )
    env = {**os.environ, "MPLBACKEND": "Agg"}
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)


def test_rl_zoo3_plot_train_draws_the_runs_episodes_from_their_monitor_files(logs: Path) -> None:
    result = rl_zoo3_plot("plot_train", "-a", "sac", "-e", NAME, "-f", str(logs), "-w", "1")
    assert result.returncode == 0, result.stderr[-3000:]
    # one curve, a point per finished episode of the 4 sub-envs
    assert result.stdout.strip().splitlines()[-1] == "points [4]", result.stdout


def test_rl_zoo3_all_plots_reads_the_runs_evaluations(logs: Path) -> None:
    result = rl_zoo3_plot("all_plots", "-a", "sac", "-e", NAME, "-f", str(logs), "--no-display")
    assert result.returncode == 0, result.stderr[-3000:]
    assert "Eval not found" not in result.stdout
    with np.load(RunFolder.at(logs, "sac", ENV_ID, 1).path / "evaluations_train.npz") as train:
        last = float(train["results"][-1].mean())
    table_row = next(line for line in result.stdout.splitlines() if line.startswith(f"|{NAME}"))
    assert f"{last:.0f} +/- 0" in table_row, result.stdout
    assert result.stdout.strip().splitlines()[-1] == "points [2]"  # the two evaluations during training
