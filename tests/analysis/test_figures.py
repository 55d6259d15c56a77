"""Smoke and unit tests of the interpretability figures (sgfd-zoo saliency-maps, weighted-samples,
classifier-accuracy) on a tiny pixel agent trained here and saved in rl-zoo3's layout."""

from __future__ import annotations

import csv
import json

import cv2
import numpy as np
import pytest
import torch
import yaml
from huggingface_sb3 import EnvironmentName

import sgfd_envs
from sb3_sgfd import SGFD_SAC
from sgfd_analysis import figures
from sgfd_cli import main as zoo_main
from sgfd_envs.families import family_kwargs
from sgfd_zoo.report.plot import mean_and_band
from sgfd_zoo.runs.folders import RunFolder, find_runs, select_run
from sgfd_zoo.vec_wrappers import wrap_like_training

ENV_ID = "SGFD/MT-walker-walk-v0"
ENV_NAME = str(EnvironmentName(ENV_ID))
ENV_KWARGS = {"obs_type": "pixels", "image_size": 32, "render": "fast"}
FRAME_STACK = 2


def write_run(folder, algo, run_id, model, seed, progress_rows=None, config=None):
    """Save a model as rl-zoo3 lays a finished run out: <algo>/<EnvName>_<id>/<EnvName>.zip + config."""
    run = folder / algo / f"{ENV_NAME}_{run_id}"
    (run / ENV_NAME).mkdir(parents=True)
    if model is not None:
        model.save(run / f"{ENV_NAME}.zip")
    # the family of envs it ran on, as a run of this version records it (sgfd_zoo.runs.folders.RunFolder.record_start)
    family = family_kwargs(ENV_ID, ENV_KWARGS)
    (run / ENV_NAME / "args.yml").write_text(yaml.dump({"seed": seed, "env_kwargs": ENV_KWARGS, "env_family": family}))
    base = {"frame_stack": FRAME_STACK, "env_kwargs": ENV_KWARGS}
    (run / ENV_NAME / "config.yml").write_text(yaml.dump({**base, **(config or {})}))
    if progress_rows is not None:
        write_progress(run / "progress.csv", progress_rows)
    return run


def write_progress(path, rows):
    fields = sorted({key for row in rows for key in row})
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=fields)
        writer.writeheader()
        writer.writerows(rows)


@pytest.fixture(scope="module")
def log_folder(tmp_path_factory):
    """A pixel SGFD agent trained for 300 steps on the 4 training domains (32x32, 2 stacked frames)."""
    folder = tmp_path_factory.mktemp("logs")
    env = wrap_like_training(sgfd_envs.make_domain_vec_env(ENV_ID, seed=0, **ENV_KWARGS), FRAME_STACK)
    model = SGFD_SAC(
        "CnnPolicy",
        env,
        buffer_size=2000,
        learning_starts=100,
        batch_size=32,
        classifier_start=150,
        policy_kwargs={"net_arch": [32, 32], "features_extractor_kwargs": {"features_dim": 16, "n_filters": 8}},
        seed=0,
    )
    model.learn(300)
    env.close()
    write_run(folder, "sgfd_sac", 1, model, seed=0)
    return folder


def decode(path):
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert image is not None, f"{path} is not a readable image"
    return image


def test_run_fixture_is_found_like_a_trained_run(log_folder):
    (run,) = find_runs(log_folder, ["sgfd_sac"], [ENV_ID])
    assert run.frame_stack == FRAME_STACK and run.env_kwargs == {**ENV_KWARGS, "robots": "hipbmdp"}


def test_action_saliency_matches_finite_differences(log_folder):
    model = select_run(log_folder, ENV_ID, "sgfd_sac").load_model()
    rng = np.random.default_rng(0)
    obs = rng.integers(0, 256, size=(2, 3 * FRAME_STACK, 32, 32)).astype(np.float32)
    saliency = figures.action_saliency(model, obs)
    assert saliency.shape == (2, 32, 32) and (saliency >= 0).all() and saliency.max() > 0

    # |d a_k / d x| summed over k and channels, against central differences on the most salient pixel.
    def actions(x):
        with torch.no_grad():
            t = torch.as_tensor(x) / 255.0
            return torch.tanh(model.actor.mu(model.actor.latent_pi(model.actor.features_extractor(t)))).numpy()

    i, j = np.unravel_index(saliency[0].argmax(), saliency[0].shape)
    total, eps = 0.0, 0.5
    for channel in range(obs.shape[1]):
        up, down = obs.copy(), obs.copy()
        up[0, channel, i, j] += eps
        down[0, channel, i, j] -= eps
        total += np.abs((actions(up)[0] - actions(down)[0]) / (2 * eps)).sum()
    np.testing.assert_allclose(saliency[0, i, j], total, rtol=0.05)


def test_saliency_maps_command_writes_a_grid_of_train_and_test_domains(log_folder, tmp_path, capsys):
    out = tmp_path / "out"
    code = zoo_main(
        [
            "saliency-maps",
            "-f",
            str(log_folder),
            "--env",
            ENV_ID,
            "--steps",
            "0,5",
            "--max-domains",
            "2",
            "-o",
            str(out),
        ]
    )
    assert code == 0
    image = decode(out / f"saliency_maps_{ENV_NAME}.png")
    # rows: train 0, train 1, interpolation 0, extrapolation 0; columns: 2 steps x (frame, map)
    height, width = image.shape[:2]
    assert (width, height) == (round(4 * figures.PANEL * figures.DPI), round((4 * figures.PANEL + 0.6) * figures.DPI))
    with np.load(out / f"saliency_maps_{ENV_NAME}.npz") as data:
        assert list(data["rows"]) == ["train 0", "train 1", "interpolation 0", "extrapolation 0"]
        assert data["saliency"].shape == (4, 2, 32, 32)
        assert data["observations"].shape == (4, 2, 3 * FRAME_STACK, 32, 32)
        assert (data["saliency"] >= 0).all() and (data["saliency"].reshape(4, -1).max(axis=1) > 0).all()
        # The stored maps are the gradients of the stored observations.
        model = select_run(log_folder, ENV_ID, "sgfd_sac").load_model()
        np.testing.assert_allclose(
            figures.action_saliency(model, data["observations"][2]), data["saliency"][2], rtol=1e-4, atol=1e-9
        )
        # Step 0 is the reset frame; the envs differ in morphology, so the frames of train 0 and 1 differ.
        assert not np.array_equal(data["observations"][0, 0], data["observations"][1, 0])
    assert "extrapolation 0" in capsys.readouterr().out


def test_weighted_samples_command_sorts_a_two_domain_batch_by_weight(log_folder, tmp_path):
    out = tmp_path / "out"
    code = zoo_main(
        [
            "weighted-samples",
            "-f",
            str(log_folder),
            "--env",
            ENV_ID,
            "--domains",
            "0,2",
            "--batch-size",
            "16",
            "--rollout-steps",
            "20",
            "--columns",
            "4",
            "-o",
            str(out),
        ]
    )
    assert code == 0
    document = json.loads((out / f"weighted_samples_{ENV_NAME}.json").read_text())
    weights = np.array(document["weights"])
    assert document["domains"] == [0] * 8 + [2] * 8
    assert len(weights) == 16 and (weights >= 0).all() and weights.sum() == pytest.approx(16, rel=1e-4)
    assert document["ess"] == pytest.approx(weights.sum() ** 2 / (weights**2).sum() / 16, rel=1e-6)
    assert set(document["mean_weight_per_domain"]) == {"0", "2"}
    assert isinstance(document["classifier_ready"], bool) and 0 <= document["classifier_accuracy"] <= 1
    image = decode(out / f"weighted_samples_{ENV_NAME}.png")
    assert image.shape[1] == round(4 * figures.PANEL * 0.8 * figures.DPI)
    assert image.std() > 10  # frames were drawn, not an empty canvas


def test_weighted_samples_figure_puts_the_heaviest_frame_first(tmp_path):
    frames = np.zeros((4, 8, 8, 3), dtype=np.uint8)
    for index in range(4):
        frames[index] = 60 * index  # frame i has brightness 60 i
    weights = np.array([0.5, 1.5, 0.2, 1.8])
    fig = figures.weighted_samples_figure(frames, weights, np.array([0, 0, 1, 1]), ["a", "b"], 2, "t")
    first_rows = [subfig.axes[0] for subfig in fig.subfigs]
    assert [ax.get_title() for ax in first_rows] == ["w=1.50", "w=1.80"]
    assert [int(ax.images[0].get_array()[0, 0, 0]) for ax in first_rows] == [60, 180]


def test_classifier_accuracy_merges_resumed_logs_and_plots_mean_and_threshold(tmp_path, capsys):
    folder = tmp_path / "logs"

    def rows(steps, accuracy):
        return [
            {"time/total_timesteps": s, "sgfd/classifier_accuracy": a} for s, a in zip(steps, accuracy, strict=True)
        ]

    run1 = write_run(
        folder,
        "sgfd_sac",
        1,
        None,
        1,
        rows([100, 200, 300, 400], [0.3, 0.6, 0.95, 0.97]),
        {"accuracy_threshold": 0.9, "classifier_start": 100},
    )
    # A crashed run resumed from its step-200 checkpoint: the resumed log replaces what came after 200.
    write_progress(run1 / "progress_from_200.csv", rows([300, 400], [0.8, 0.92]))
    write_run(
        folder,
        "sgfd_sac",
        2,
        None,
        2,
        [{"time/total_timesteps": 50, "train/critic_loss": 1.0}, *rows([100, 250, 400], [0.5, 0.7, 0.9])],
        {"accuracy_threshold": 0.9, "classifier_start": 100},
    )
    steps, accuracy = RunFolder(run1).log(figures.ACCURACY_KEY)
    np.testing.assert_array_equal(steps, [100, 200, 300, 400])
    np.testing.assert_allclose(accuracy, [0.3, 0.6, 0.8, 0.92])

    curves = figures.load_accuracy_curves(folder)
    curves_of_runs = [(curve["steps"], curve["accuracy"]) for curve in curves[ENV_ID]["sgfd_sac"]]
    grid, mean, std = mean_and_band(curves_of_runs, n_points=4)
    np.testing.assert_allclose(grid, [100, 200, 300, 400])
    np.testing.assert_allclose(mean, [0.4, (0.6 + 0.6333333) / 2, (0.8 + 0.7666667) / 2, 0.91], rtol=1e-5)
    assert std[0] == pytest.approx(0.1)

    assert zoo_main(["classifier-accuracy", "-f", str(folder)]) == 0
    printed = capsys.readouterr().out
    # Interpolated, the mean crosses 0.9 at step 392.1; the first of 200 grid points past it is 392.5.
    assert "2 run(s), final mean accuracy 0.910, mean first >= 0.9 at step 392" in printed
    fig = figures.accuracy_figure(ENV_ID, curves[ENV_ID])
    ax = fig.axes[0]
    assert any(tuple(line.get_ydata()) == (0.9, 0.9) and line.get_color() == "red" for line in ax.lines)
    image = decode(folder / "figures" / f"classifier_accuracy_{ENV_NAME}.png")
    assert image.shape[:2] == (380, 600)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["saliency-maps", "-f", "{folder}", "--env", "SGFD/nope-v0"], "not a registered id"),
        (["saliency-maps", "-f", "{folder}", "--env", "SGFD/MT-cheetah-run-v0"], "no finished sgfd_sac run"),
        (["saliency-maps", "-f", "{folder}", "--env", ENV_ID, "--steps", "a,b"], "--steps must be"),
        (["saliency-maps", "-f", "{folder}", "--env", ENV_ID, "--exp-id", "7"], "choose from [1]"),
        (["weighted-samples", "-f", "{folder}", "--env", ENV_ID, "--domains", "0,9"], "two different training domains"),
        (["weighted-samples", "-f", "{folder}", "--env", ENV_ID, "--batch-size", "7"], "even number"),
        (["classifier-accuracy", "-f", "{folder}/missing"], "does not exist"),
    ],
)
def test_bad_input_is_one_clear_line(log_folder, args, message, capsys):
    args = [arg.replace("{folder}", str(log_folder)) for arg in args]
    assert zoo_main(args) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1


def test_classifier_accuracy_without_logged_accuracy_is_refused(log_folder, capsys):
    # The fixture's run has no progress.csv: nothing to plot.
    assert zoo_main(["classifier-accuracy", "-f", str(log_folder)]) == 2
    assert "logged sgfd/classifier_accuracy" in capsys.readouterr().err
