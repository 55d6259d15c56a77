"""Runs on a GPU node, before any starts: the packing rule, ``--gpus-per-run``, and ``sgfd-zoo study SPEC --plan``
(the runs, the updates each, GPU-hours and wall time from the committed rate table) on the committed paper specs."""

from __future__ import annotations

import argparse
import csv
import subprocess
import sys
from pathlib import Path

import pytest

import sgfd_cli as cli
from sgfd_zoo.arguments import ZooError
from sgfd_zoo.sweep import cost
from sgfd_zoo.sweep.plan import MAX_RUNS_PER_GPU, TRANSITION_EXTRA_BYTES, packing, replay_bytes, run_resources

REPO = Path(__file__).resolve().parents[2]
PAPER_SPECS = {"paper-table1": "SGFD/walker-walk-v0", "paper-table2": "SGFD/MT-walker-walk-v0"}
COLUMNS = ["sgfd_sac", "ted", "ambs", "sgqn", "dbc", "sac"]


@pytest.mark.parametrize(
    ("cores_per_gpu", "envs", "runs", "cpus", "env_processes"),
    [
        (16, 4, 8, 2, 4),  # the measured H200 host: a learner core and a core for 4 env processes, 8 runs
        (8, 4, 4, 2, 4),
        (12, 4, 6, 1.9992, 4),  # 1/6 of a GPU rounded down to Ray's step, so that 6 fit
        (2, 4, 1, 2, 4),
        (1, 4, 1, 1, 4),  # never less than one run a GPU
        (64, 4, MAX_RUNS_PER_GPU, 8, 4),  # at most 8 runs on a GPU; each then reserves more cores
        (16, 1, 8, 2, 0),  # one env: it steps in the run's own process
    ],
)
def test_the_packing_rule_feeds_each_run_a_core_for_its_learner_and_one_per_four_env_processes(
    cores_per_gpu: int, envs: int, runs: int, cpus: float, env_processes: int
) -> None:
    rule = packing(cores_per_gpu, envs)
    assert rule.runs_per_gpu == runs
    assert rule.gpus_per_run * runs <= 1 < rule.gpus_per_run * (runs + 1)
    assert rule.cpus_per_run == pytest.approx(cpus, abs=1e-3)
    assert rule.env_processes == env_processes and rule.torch_threads == 1


def test_a_gpu_fraction_asked_for_is_kept_and_reserves_the_gpus_share_of_the_cores() -> None:
    rule = packing(16, 4, gpus_per_run=0.25)
    assert (rule.runs_per_gpu, rule.gpus_per_run, rule.cpus_per_run) == (4, 0.25, 4)
    assert str(rule) == "4 runs per GPU (--gpus-per-run 0.25); each 4 CPUs, 1 torch thread and 4 env processes"


def namespace(**values: object) -> argparse.Namespace:
    defaults = {"gpus_per_run": None, "cpus_per_run": None, "envs_per_run": 4, "replay_bytes": 0}
    return argparse.Namespace(**{**defaults, **values})


def test_a_gpu_holds_no_more_runs_than_their_replay_buffers_fit_in_its_share_of_the_memory() -> None:
    # The paper's pixel runs: a million transitions, each frame stored once (3 x 84 x 84 bytes, and its action,
    # reward and labels): 21.2 GB a run
    paper = replay_bytes(["sgfd_sac", "ambs"], ["SGFD/walker-walk-v0"])
    assert paper == 1_000_000 * (3 * 84 * 84 + TRANSITION_EXTRA_BYTES)
    assert replay_bytes(["sgfd_sac"], ["SGFD/MT-walker-walk-v0"], quick=True) < 0.1e9  # the quick job's states
    node = 128 * 2**30  # an H200 host's 128 GiB, one GPU: 3/4 of it holds 4 such buffers, not the cores' 8
    rule = packing(16, 4, memory_per_gpu=node, replay_bytes=paper)
    assert rule.runs_per_gpu == 4 and packing(16, 4).runs_per_gpu == 8
    assert str(rule).endswith("4 env processes, a replay buffer of 21.2 GB")
    assert packing(16, 4, memory_per_gpu=4 * node, replay_bytes=paper).runs_per_gpu == 8  # the cores bound it then
    args = namespace(replay_bytes=paper)
    _, packed = run_resources(args, [], cores_per_gpu=16, memory_per_gpu=node)
    assert packed is not None and packed.runs_per_gpu == 4 and args.gpus_per_run == 0.25
    with pytest.raises(ZooError, match=r"a run's replay buffer takes 21.2 GB, more than the 10.0 GB of memory per GPU"):
        run_resources(namespace(replay_bytes=paper), [], cores_per_gpu=16, memory_per_gpu=10e9)


def test_without_a_gpu_a_run_reserves_one_cpu_and_one_thread_as_before() -> None:
    args = namespace()
    train_args, packed = run_resources(args, ["--quick"], cores_per_gpu=None)
    assert packed is None and (args.gpus_per_run, args.cpus_per_run) == (0, 1)
    assert train_args == ["--quick", "--num-threads", "1"]
    args = namespace(cpus_per_run=2.0)
    assert run_resources(args, [], None)[0] == ["--num-threads", "2"]


def test_on_a_gpu_node_the_rule_sets_what_the_user_left_open() -> None:
    args = namespace()
    train_args, packed = run_resources(args, ["--quick"], cores_per_gpu=16)
    assert packed is not None and (args.gpus_per_run, args.cpus_per_run) == (0.125, 2)
    assert train_args == ["--quick", "--num-threads", "1", "--vec-env", "subproc"]
    args = namespace(gpus_per_run=0.5, cpus_per_run=3.0)
    train_args, _ = run_resources(args, ["--vec-env", "dummy", "--num-threads", "4"], cores_per_gpu=16)
    assert (args.gpus_per_run, args.cpus_per_run) == (0.5, 3)
    assert train_args == ["--vec-env", "dummy", "--num-threads", "4"]
    args = namespace(gpus_per_run=0.0)  # --gpus-per-run 0 on a GPU node: CPU runs, as before
    assert run_resources(args, [], cores_per_gpu=16) == (["--num-threads", "1"], None)


@pytest.mark.parametrize(
    ("value", "message"),
    [
        ("abc", "--gpus-per-run 'abc': expected a fraction of a GPU such as 0.25"),
        ("-0.5", "--gpus-per-run -0.5: expected"),
        ("nan", "--gpus-per-run nan: expected"),
        ("1.5", "--gpus-per-run 1.5: Ray gives a run more than one GPU only whole"),
        ("0.00001", "--gpus-per-run 0.00001: Ray counts GPUs in steps of 0.0001"),
    ],
)
@pytest.mark.parametrize("command", ["sweep", "study"])
def test_a_bad_gpu_fraction_is_refused_in_one_line_naming_the_flag(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str, value: str, message: str
) -> None:
    if command == "sweep":
        argv = ["sweep", "--algos", "sac", "--envs", "SGFD/walker-walk-v0", "--seeds", "0", "-f", str(tmp_path)]
    else:
        argv = ["study", str(REPO / "studies" / "paper-table1" / "spec.yml"), "-f", str(tmp_path), "--plan"]
    assert cli.main([*argv, "--gpus-per-run", value]) == 2
    # (the first import of rl-zoo3 in a process may print gym's notice before it)
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(f"sgfd-zoo {command}: error: ") and message in err[-1], err
    assert not any(line.startswith("Traceback") for line in err) and not list(tmp_path.iterdir())


def plan_output(spec: str, *flags: str) -> str:
    """``sgfd-zoo study studies/<spec>/spec.yml --plan`` in a fresh interpreter, which must import neither torch nor
    Ray (a plan builds and trains nothing)."""
    check = (
        "import sys; import sgfd_cli as cli; code = cli.main(sys.argv[1:]); "
        "assert not {'torch', 'ray'} & set(sys.modules), 'a plan imported the training stack'; sys.exit(code)"
    )
    argv = ["study", f"studies/{spec}/spec.yml", "--plan", *flags]
    done = subprocess.run([sys.executable, "-c", check, *argv], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    return done.stdout


def rate_table() -> dict[tuple[str, int], float]:
    """The committed table's newest check, read here without the package: (algo, runs at once) -> updates/s in all,
    and ("envs", runs at once) -> env steps/s in all."""
    with cost.RATES_FILE.open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    newest = [row for row in rows if row["date"] == max(row["date"] for row in rows)]
    figure = {True: "env_steps_per_s", False: "updates_per_s"}
    return {(row["algo"], int(row["runs_at_once"])): float(row[figure[row["algo"] == "envs"]]) for row in newest}


def run_hours(updates_per_s: float, env_steps_per_s: float, env_steps_per_update: float = 1.0) -> float:
    """A paper-scale run's hours: 200,800 updates at the learner's own rate (the learning run's, its env steps taken
    out) and 1e6 env steps."""
    update_seconds = 1 / updates_per_s - env_steps_per_update / env_steps_per_s
    return (200_800 * update_seconds + 1_000_000 / env_steps_per_s) / 3600


@pytest.mark.slow
@pytest.mark.parametrize("spec", PAPER_SPECS)
def test_the_plan_of_a_paper_table_counts_its_runs_and_costs_them_at_the_measured_rates(spec: str) -> None:
    out = plan_output(spec)
    assert out.startswith(f"study {spec}: 6 algos x 5 envs x 5 seeds = 150 runs at the zoo's paper settings")
    # the authors' protocol: 1e6 transitions; 1000 updates at once after the first 1000, then one per 5 transitions
    assert (
        "150 to train" in out
        and "updates per run: 200,800\n" in out
        and "per run (physics and render): 1,000,000" in out
    )
    assert "packing on that machine: 8 runs per GPU (--gpus-per-run 0.125); each 2 CPUs" in out
    rates = rate_table()
    env_rate = rates["envs", 1]
    alone = 25 * run_hours(rates["sgfd_sac", 1], env_rate)
    # 8 at once: the measured per-run update rate; the env-step rate slowed as much (the check measured it alone)
    sharing = rates["sgfd_sac", 8] / 8 / rates["sgfd_sac", 1]
    packed = 25 * run_hours(rates["sgfd_sac", 8] / 8, env_rate * sharing) / 8
    sgfd = f"| SGFD (sgfd_sac) | 25 | {1 / (1 / rates['sgfd_sac', 1] - 1 / env_rate):.1f} | {env_rate:.0f} | "
    assert sgfd + f"{alone:.1f} | " in out and f"~{packed:.1f} |" in out
    # AMBS measured alone only: its packed rate is its own scaled by SGFD's measured 8-at-once ratio, and marked
    ratio = rates["sgfd_sac", 8] / rates["sgfd_sac", 1]
    ambs_packed = 25 * run_hours(rates["ambs", 1] * ratio / 8, env_rate * sharing) / 8
    ambs_alone = 25 * run_hours(rates["ambs", 1], env_rate)
    assert f"| AMBS (ambs) | 25 | {1 / (1 / rates['ambs', 1] - 1 / env_rate):.1f} | " in out
    assert f" | {ambs_alone:.1f} | " in out and f"~{ambs_packed:.1f} |" in out
    unrated = [algo for algo in COLUMNS if (algo, 1) not in rates]
    for algo in unrated:
        assert f"({algo}) | 25 | no measured rate on pixels | – |" in out
    assert f"total, the {150 - 25 * len(unrated)} of 150 runs with a rate" in out
    assert f"{packed + ambs_packed:.1f} at 8 per GPU" in out


@pytest.mark.slow
def test_the_plans_wall_time_fills_the_gpus_it_is_given() -> None:
    one, eight = plan_output("paper-table1"), plan_output("paper-table1", "--gpus", "8", "--gpus-per-run", "0.25")
    assert "on 1 such GPU (16 cores each), 8 runs on each: 47.6 h (2.0 days)" in one
    assert "packing on that machine: 4 runs per GPU (--gpus-per-run 0.25); each 4 CPUs" in eight
    assert "on 8 such GPUs (16 cores each), 4 runs on each:" in eight


def test_wall_time_puts_each_run_on_the_first_free_place() -> None:
    assert cost.wall_hours([1.0, 1.0, 1.0], slots=2) == 2.0
    assert cost.wall_hours([3.0, 1.0, 1.0, 1.0], slots=2) == 3.0
    assert cost.wall_hours([], slots=4) == 0.0


def test_the_plan_uses_the_latest_check_only_and_names_what_it_did_not_measure(tmp_path: Path) -> None:
    rates = tmp_path / "rates.csv"
    rows = cost.RATES_FILE.read_text().splitlines()
    later = "2027-01-10,NVIDIA H200,16,1,sgfd_sac,pixels,SGFD/walker-walk-v0,1,40.0,5,,captured,a later check"
    envs = "2027-01-10,NVIDIA H200,16,1,envs,pixels,SGFD/walker-walk-v0,1,,,2000,,4 env processes"
    rates.write_text("\n".join([*rows, later, envs]) + "\n")
    runs = cost.plan_runs(["sgfd_sac", "ambs"], ["SGFD/walker-walk-v0"], [0, 1], [], n_episodes=10)
    lines = cost.cost_lines(runs, gpus=1, gpus_per_run=None, rates_file=rates)
    assert "the device check of 2027-01-10" in lines[0] and "captured update" in lines[0]
    assert "(the check measured at most 1 run at once on a GPU: the plan packs 1 run per GPU)" in lines
    # 5 env steps inside each measured update: the learner alone makes 1 / (1/40 - 5/2000) = 44.4 updates/s
    hours = 2 * run_hours(40.0, 2000.0, env_steps_per_update=5)
    assert f"| SGFD (sgfd_sac) | 2 | 44.4 | 2000 | {hours:.1f} | 44.4 | 2000 | {hours:.1f} |" in lines
    assert "| AMBS (ambs) | 2 | no measured rate on pixels | – | – | – | – | – |" in lines
    assert "measured: envs, 1 at once: 2000 env steps/s in all (4 env processes)" in lines


def test_a_plan_counts_the_specs_own_steps_and_evaluations() -> None:
    train = ["-n", "30000", "--eval-freq", "5000", "--eval-episodes", "8", "-params", "learning_starts:2000"]
    (run,) = cost.plan_runs(["sac"], ["SGFD/MT-walker-walk-v0"], [0], train, n_episodes=10)
    # one update per 5 of the 28k transitions after learning starts, and the burst of 1000
    assert (run.updates, run.env_steps, run.observations) == (28_000 // 5 + 1000, 30_000, "pixels")
    assert (run.eval_episodes, run.final_episodes) == (6 * 8 * 3, 10 * 3)  # train, interpolation, extrapolation
    (run,) = cost.plan_runs(["sac"], ["SGFD/MT-walker-walk-v0"], [0], ["--quick"], n_episodes=10)
    assert run.observations == "state"


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("date,machine\n", "expected the columns date, machine, cores"),
        (",".join(cost.RATE_COLUMNS) + "\n2026-12-04,H200,16,1,sac,pixels,X,1,fast,1,,eager,\n", "line 2: not a rate"),
        (",".join(cost.RATE_COLUMNS) + "\n2026-12-04,H200,16,1,sac,pixels,X,0,9,1,,eager,\n", "line 2: cores, gpus"),
        (",".join(cost.RATE_COLUMNS) + "\n2026-12-04,H200,16,1,sac,pixels,X,1,,1,,eager,\n", "updates_per_s > 0"),
        (",".join(cost.RATE_COLUMNS) + "\n2026-12-04,H200,16,1,envs,pixels,X,1,,,0,,\n", "env_steps_per_s > 0"),
    ],
)
def test_a_bad_rate_table_is_named_in_one_line(tmp_path: Path, text: str, message: str) -> None:
    rates = tmp_path / "rates.csv"
    rates.write_text(text)
    with pytest.raises(ZooError, match=message) as error:
        cost.read_rates(rates)
    assert str(rates) in str(error.value)


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--gpus", "0"], "--gpus must be >= 1, got 0"),
        (["--gpus", "2"], "--gpus sizes the --plan's wall time"),
    ],
)
def test_the_plans_gpu_count_is_checked(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], flags: list[str], message: str
) -> None:
    plan = ["--plan"] if flags[1] == "0" else []
    argv = ["study", str(REPO / "studies" / "paper-table2" / "spec.yml"), "-f", str(tmp_path), *plan, *flags]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
