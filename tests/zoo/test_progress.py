"""The sweep's live progress: the runs' reports, their lines, and how they are shown."""

from __future__ import annotations

import io
from types import SimpleNamespace

import numpy as np

import sgfd_envs
from sb3_sgfd import EncoderSAC
from sgfd_zoo import callbacks, training
from sgfd_zoo.callbacks import MultiSplitEvalCallback, ProgressCallback
from sgfd_zoo.sweep.progress import LiveView, ProgressBoard, duration, progress_block, progress_line


def test_a_run_reports_its_steps_rate_end_and_latest_evaluation():
    reports: list[dict] = []
    env = sgfd_envs.make_domain_vec_env("SGFD/MT-walker-walk-v0", obs_type="state")
    model = EncoderSAC("MlpPolicy", env, learning_starts=50, batch_size=16, policy_kwargs=dict(net_arch=[16]))
    evaluation_env = sgfd_envs.make_domain_vec_env("SGFD/MT-walker-walk-v0", split="extrapolation", obs_type="state")
    evaluation = MultiSplitEvalCallback({"extrapolation": evaluation_env}, eval_freq=30, n_eval_episodes=1, verbose=0)
    progress = ProgressCallback(reports.append, 120, evaluation.latest_returns, interval=0.0)
    model.learn(120, callback=[evaluation, progress])  # one evaluation, at the last step
    assert reports[0]["steps"] == 0 and not reports[0]["done"] and "returns" not in reports[0]
    assert reports[-1] == {**reports[-1], "steps": 120, "total": 120, "done": True}
    assert reports[-1]["returns"] == evaluation.latest_returns() and "extrapolation" in reports[-1]["returns"]
    steps = [report["steps"] for report in reports]
    assert steps == sorted(steps) and len(reports) > 3
    assert reports[-1]["steps_per_second"] > 0


def test_the_board_keeps_each_runs_latest_report():
    board = ProgressBoard()
    board.report("a", {"steps": 1})
    board.report("a", {"steps": 5})
    board.report("b", {"steps": 2})
    snapshot = board.snapshot()
    assert {key: value["steps"] for key, value in snapshot.items()} == {"a": 5, "b": 2}


def test_progress_lines_show_steps_rate_eta_and_the_latest_returns():
    report = {"steps": 5000, "total": 20000, "steps_per_second": 50.0, "returns": {"train": 312.44, "extrapolation": 8}}
    line = progress_line("sgfd_sac MT-walker-walk seed 0", report)
    assert "5000/20000" in line and " 25%" in line and "50 steps/s" in line
    assert "ETA  5m00s" in line and "last eval: train 312.4, extrapolation 8.0" in line
    # a run at its end: no ETA
    assert "ETA      -" in progress_line("x", {**report, "steps": 20000})
    assert (duration(3725), duration(245), duration(7)) == ("1h02m", "4m05s", "7s")


def test_the_block_shows_the_runs_under_way_and_counts_the_others():
    names = ["a", "b", "c", "d"]
    reports = {"a": {"steps": 10, "total": 20}, "b": {"steps": 20, "total": 20}, "c": {"steps": 5, "total": 20}}
    lines = progress_block(names, reports, {"b": "finished", "c": "FAILED"})
    assert len(lines) == 2 and lines[0].startswith("a ") and "10/20" in lines[0]
    assert lines[1] == "1 running, 1 waiting, 1 finished, 1 failed"


def test_in_a_log_the_block_is_printed_at_the_interval_and_at_the_end():
    stream = io.StringIO()
    with LiveView(interval=3600.0, stream=stream) as view:
        view.show(["first"])
        view.show(["second"])  # within the interval: not printed
        view.message("[1/2] finished")
        view.show(["last"], force=True)
    text = stream.getvalue()
    assert "first" in text and "second" not in text and "last" in text
    assert text.count("--- sweep progress") == 2 and "[1/2] finished\n" in text


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_on_a_terminal_the_block_redraws_in_place_and_its_final_state_stays():
    stream = Terminal()
    with LiveView(interval=3600.0, stream=stream) as view:
        for step in range(3):
            view.show([f"run a {step}/2", f"run b {step}/2"])
        view.message("[1/2] finished a")
    text = stream.getvalue()
    assert "[1/2] finished a" in text
    # after the live block, its final state once, as plain lines
    assert text.rstrip().endswith("run a 2/2\nrun b 2/2")
    assert "--- sweep progress" not in text


def test_a_restarted_run_replaces_the_evaluations_its_interrupted_attempt_made_later(tmp_path):
    # An attempt that was stopped at 90 steps without a checkpoint: the run starts again from step 0.
    np.savez(
        tmp_path / "evaluations_extrapolation.npz",
        timesteps=np.array([30, 60, 90]),
        results=np.zeros((3, 1)),
        ep_lengths=np.full((3, 1), 1000),
    )
    env = sgfd_envs.make_domain_vec_env("SGFD/MT-walker-walk-v0", obs_type="state")
    model = EncoderSAC("MlpPolicy", env, learning_starts=50, batch_size=16, policy_kwargs=dict(net_arch=[16]))
    evaluation_env = sgfd_envs.make_domain_vec_env("SGFD/MT-walker-walk-v0", split="extrapolation", obs_type="state")
    evaluation = MultiSplitEvalCallback(
        {"extrapolation": evaluation_env}, eval_freq=15, n_eval_episodes=1, log_path=tmp_path, verbose=0
    )
    model.learn(60, callback=evaluation)  # 4 sub-envs: evaluations at 60 steps only
    with np.load(tmp_path / "evaluations_extrapolation.npz") as data:
        assert data["timesteps"].tolist() == [60]
        assert data["results"].shape == (1, 1) and data["results"][0, 0] != 0


class Clock:
    """A monotonic clock the test moves."""

    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def test_the_rate_and_eta_count_learning_steps_only(monkeypatch):
    # 1000 random-action steps in 1 s, then 100 learning steps in 10 s: the run goes on at 10 steps/s, not 100.
    clock = Clock()
    monkeypatch.setattr(callbacks.time, "monotonic", clock)
    reports: list[dict] = []
    model = SimpleNamespace(num_timesteps=0, learning_starts=1000, get_env=lambda: None, logger=None)
    progress = ProgressCallback(reports.append, 20_000, interval=0.5)
    progress.init_callback(model)
    progress.on_training_start({}, {})
    for steps, now in ((500, 1000.5), (1000, 1001.0), (1050, 1006.0), (1100, 1011.0)):
        model.num_timesteps, clock.now = steps, now
        progress.on_step()
    warm_up, learning = reports[1], reports[-1]
    assert warm_up["steps"] == 500 and warm_up["steps_per_second"] == 0 and warm_up["learning_starts"] == 1000
    assert "warm-up to step 1000" in progress_line("run", warm_up) and "ETA" not in progress_line("run", warm_up)
    assert learning["steps"] == 1100 and learning["steps_per_second"] == 10.0
    assert "10 steps/s  ETA 31m30s" in progress_line("run", learning)  # 18900 steps left at 10 steps/s
    # at the step learning starts (where the quick job's first evaluation falls) no pace is measured yet: said so
    at_start = reports[2]
    assert at_start["steps"] == 1000 and at_start["steps_per_second"] == 0
    assert "pace measured at the next report" in progress_line("run", at_start)
    assert "steps/s" not in progress_line("run", at_start)


def test_an_evaluation_is_reported_as_it_starts_each_split_and_as_it_ends():
    reports: list[dict] = []
    env = sgfd_envs.make_domain_vec_env("SGFD/MT-walker-walk-v0", obs_type="state")
    model = EncoderSAC("MlpPolicy", env, learning_starts=50, batch_size=16, policy_kwargs=dict(net_arch=[16]))
    splits = ("interpolation", "extrapolation")
    evaluation_envs = {
        split: sgfd_envs.make_domain_vec_env("SGFD/MT-walker-walk-v0", split=split, obs_type="state")
        for split in splits
    }
    evaluation = MultiSplitEvalCallback(evaluation_envs, eval_freq=15, n_eval_episodes=1, verbose=0)
    progress = ProgressCallback(reports.append, 60, evaluation.latest_returns, interval=3600.0)
    evaluation.on_split = progress.evaluating  # as the zoo's runs wire them
    model.learn(60, callback=[evaluation, progress])  # 4 sub-envs: one evaluation, at 60 steps
    evaluating = [report.get("evaluating") for report in reports]
    # the start, each split as it starts, the end of the evaluation, the end of the run
    assert evaluating == [None, "interpolation", "extrapolation", None, None]
    assert all(report["steps"] == 60 for report in reports[1:])
    assert "evaluating interpolation for 0s" in progress_line("run", reports[1], now=reports[1]["evaluating_since"])
    later = progress_line("run", reports[2], now=reports[2]["evaluating_since"] + 65)
    assert "evaluating extrapolation for 1m05s" in later and "ETA" not in later
    after = progress_line("run", reports[3])
    assert "evaluating" not in after and "last eval: interpolation" in after and "extrapolation" in after


def test_a_zoo_run_reports_its_evaluations_and_warm_up_to_the_sweep(tmp_path):
    reports: list[dict] = []
    argv = ["--algo", "sac", "--env", "SGFD/MT-walker-walk-v0", "--quick", "-n", "80", "-f", str(tmp_path)]
    argv += ["--eval-freq", "80", "--eval-episodes", "1", "--no-progress", "--verbose", "0", "--num-threads", "1"]
    argv += ["-params", "learning_starts:40", "batch_size:16", "policy_kwargs:dict(net_arch=[16])"]
    training.train(argv, progress_reporter=reports.append)
    assert reports[0]["learning_starts"] == 40 and "warm-up to step 40" in progress_line("run", reports[0])
    assert [r["evaluating"] for r in reports if "evaluating" in r] == ["train", "interpolation", "extrapolation"]
    assert reports[-1]["done"] and "evaluating" not in reports[-1]
