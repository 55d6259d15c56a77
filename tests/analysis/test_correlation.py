"""sgfd-zoo correlation-study: states from the MT training domains, the changed parameter appended, and
the mean |correlation| of that feature with the others under raw, global and SGFD weights."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

import sgfd_envs
from sgfd_analysis import correlation
from sgfd_cli import main as zoo_main
from sgfd_zoo.arguments import ZooError

ENV_ID = "SGFD/MT-walker-walk-v0"
# Reduced but honest: all four training domains, 8 batches of 128 instead of 31, the defaults otherwise.
STEPS = 256
SHORT = ["--env", ENV_ID, "--steps-per-domain", "8"]


@pytest.fixture(scope="module")
def walker_study(tmp_path_factory):
    out = tmp_path_factory.mktemp("study")
    code = zoo_main(["correlation-study", "--env", ENV_ID, "--out", str(out), "--steps-per-domain", str(STEPS)])
    assert code == 0
    return out


def test_collect_states_appends_each_domains_morphology_value():
    sample = correlation.collect_states(ENV_ID, steps_per_domain=20, seed=3)
    assert sample.features.shape == (4 * 20, 10)
    assert sample.names[:2] == ["orientations[0]", "orientations[1]"] and sample.names[-1] == "left_foot_half_length"
    assert sample.changed == 9
    expected = []
    for domain in range(4):
        env = sgfd_envs.make_domain_vec_env(ENV_ID, "train", obs_type="state").envs[domain].unwrapped
        expected.append(env.morphology_value)
    for domain in range(4):
        rows = sample.features[sample.domains == domain]
        np.testing.assert_array_equal(rows[:, -1], expected[domain])
    # Domain i's first state is the reset state under seed 3 + i: the same seed gives the same states.
    again = correlation.collect_states(ENV_ID, steps_per_domain=20, seed=3)
    np.testing.assert_array_equal(sample.features, again.features)
    other = correlation.collect_states(ENV_ID, steps_per_domain=20, seed=4)
    assert not np.array_equal(sample.features, other.features)


def test_features_by_name_pick_those_columns():
    names = ["height", "velocity[0]"]
    sample = correlation.collect_states(ENV_ID, steps_per_domain=5, features=names)
    assert sample.names == [*names, "left_foot_half_length"]
    full = correlation.collect_states(ENV_ID, steps_per_domain=5, n_state_features=24)
    np.testing.assert_array_equal(sample.features[:, 0], full.features[:, 14])  # height is entry 14
    np.testing.assert_array_equal(sample.features[:, 1], full.features[:, 15])


def test_study_json_has_the_three_weightings_and_the_goals_hold(walker_study, capsys):
    document = json.loads((walker_study / "correlation.json").read_text())
    raw, glob, sgfd = (document[key]["mean_abs_corr"] for key in ("raw", "global", "sgfd"))
    assert document["raw"]["ess"] == pytest.approx(1.0)
    assert document["n_batches"] == 4 * STEPS // 128 and document["batch_size"] == 128
    assert document["changed_feature"] == "s10 left_foot_half_length" and len(document["features"]) == 10
    # The matrices are the figures: the changed feature's row gives the reported mean |r|.
    for key, value in (("raw", raw), ("global", glob), ("sgfd", sgfd)):
        matrix = np.array(document["matrices"][key])
        assert matrix.shape == (10, 10)
        np.testing.assert_allclose(np.diag(matrix), 1.0, atol=1e-5)
        assert matrix[9, :9].mean() == pytest.approx(value, abs=1e-5)
    # The goals, on this reduced configuration.
    assert sgfd < glob < raw
    assert sgfd <= 0.65 * raw
    assert document["sgfd"]["ess"] >= 0.5
    assert all(document["goals"].values())
    assert document["classifier_accuracy"] > 0.5  # four domains: chance is 0.25


def test_study_png_shows_three_heat_maps(walker_study):
    image = cv2.imread(str(walker_study / "correlation.png"))
    assert image is not None
    height, width = image.shape[:2]
    assert width > 2.5 * height  # three square panels side by side
    # Each panel is a 10x10 grid drawn with the Blues map: its darkest cells are the diagonal's |r| = 1.
    blue = (image[:, :, 0].astype(int) - image[:, :, 2].astype(int)) > 80
    columns = np.flatnonzero(blue.any(axis=0))
    regions = np.split(columns, np.flatnonzero(np.diff(columns) > 20) + 1)
    # three panels of equal width, each over a fifth of the figure, then the narrow colour bar
    widths = [len(region) for region in regions]
    assert len(widths) == 4, widths
    assert min(widths[:3]) > 0.2 * width and max(widths[:3]) - min(widths[:3]) <= 2
    assert widths[3] < 0.05 * width


def test_report_prints_the_figures_and_goals():
    result = correlation.StudyResult(
        names=["a", "b", "m"],
        changed=2,
        matrices={},
        mean_abs_corr={"raw": 0.2, "global": 0.15, "sgfd": 0.14},
        ess={"raw": 1.0, "global": 0.6, "sgfd": 0.45},
        classifier_accuracy=0.9,
        n_batches=3,
        batch_size=128,
    )
    text = correlation.report(result)
    assert "sgfd < global < raw (0.1400 < 0.1500 < 0.2000): met" in text
    assert "sgfd <= 0.65 x raw (ratio 0.700): NOT MET" in text
    assert "SGFD's ESS >= 0.5 n (0.450 n): NOT MET" in text


def test_weights_see_the_changed_feature_through_the_classifier():
    sample = correlation.collect_states(ENV_ID, steps_per_domain=128, seed=1)
    result = correlation.correlation_study(sample, batch_size=128, seed=1)
    # The torso length is the only feature that tells the domains apart for sure: the saliency finds it.
    assert result.extra["mean_changed_feature_probability"] > 0.5
    # A different seed gives other batches and RFFs, hence other numbers.
    other = correlation.correlation_study(sample, batch_size=128, seed=2)
    assert other.mean_abs_corr["sgfd"] != result.mean_abs_corr["sgfd"]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--env", "SGFD/walker-walk-v0"], "has no per-domain parameter"),
        (["--env", "SGFD/MT-walker-walk-v0", "--steps-per-domain", "1"], "--steps-per-domain must be >= 2"),
        ([*SHORT, "--features", "height,nope"], "unknown ['nope']"),
        ([*SHORT, "--n-state-features", "99"], "must be in 1..24"),
        ([*SHORT, "--batch-size", "64"], "--batch-size must be"),
    ],
)
def test_bad_input_is_one_clear_line(args, message, tmp_path, capsys):
    assert zoo_main(["correlation-study", "--out", str(tmp_path), *args]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1


def test_constant_changed_feature_is_refused():
    sample = correlation.StateSample(
        np.random.default_rng(0).normal(size=(256, 3)), np.repeat([0, 1], 128), ["a", "b", "m"], 2
    )
    sample.features[:, 2] = 1.0
    with pytest.raises(ZooError, match="same value in every domain"):
        correlation.correlation_study(sample)
