"""Nothing saved is misread: a run records the family of envs it trains on (``env_family`` in its args.yml), and a
run recorded before the SGFD ids had families (version 0.1.0's, tests/data/legacy) is evaluated and resumed on the
envs of that time (sgfd_envs.families.EARLIER_FAMILY), not on today's defaults."""

from __future__ import annotations

import shutil
from pathlib import Path

import sgfd_envs
from sgfd_zoo.runs.folders import RunFolder
from sgfd_zoo.runs.resuming import envs_as_trained

LEGACY_RUN = Path(__file__).parents[1] / "data" / "legacy" / "0.1.0" / "train_folder"


def legacy_run(tmp_path: Path) -> RunFolder:
    shutil.copytree(LEGACY_RUN, tmp_path / "logs")
    return RunFolder(tmp_path / "logs" / "sgfd_sac" / "SGFD-MT-walker-walk-v0_1")


def test_a_run_of_version_0_1_0_is_evaluated_on_the_scaled_robots_it_trained_on(tmp_path):
    run = legacy_run(tmp_path)
    assert run.args and "env_family" not in run.args
    assert run.env_kwargs == {"obs_type": "state", "observe_parameter": True, "robots": "scaled"}
    for split, settings in (("train", [1, 2, 4, 5]), ("interpolation", [3])):  # the splits of its time
        venv = sgfd_envs.make_domain_vec_env(run.env_id, split, **run.env_kwargs)
        try:
            assert venv.get_attr("setting") == settings
        finally:
            venv.close()


def test_a_resumed_run_of_version_0_1_0_goes_on_on_its_family_where_the_flags_name_none(tmp_path):
    run = legacy_run(tmp_path)
    given, evaluation = {"obs_type": "state"}, {"obs_type": "state", "robots": "hipbmdp"}
    train, evaluate = envs_as_trained(run, run.env_id, given, evaluation)
    assert train == {"obs_type": "state", "robots": "scaled"}
    assert evaluate == evaluation  # a family named is kept


def test_a_run_started_now_records_its_family_and_is_read_back_on_it(tmp_path):
    for env_id, family in (
        ("SGFD/MT-walker-walk-v0", {"robots": "hipbmdp"}),
        ("SGFD/walker-walk-v0", {"robots": "hipbmdp", "backgrounds": "still", "compositing": "colour_key"}),
        ("DMCGB/walker-walk-v0", {}),
    ):
        run = RunFolder.at(tmp_path, "sac", env_id, 1)
        run.record_start({"env_kwargs": {"obs_type": "state"}}, {"seed": 0}, None, step=0)
        recorded = RunFolder(run.path)
        assert {k: v for k, v in recorded.args["env_family"].items() if v is not None} == family
        assert {k: v for k, v in recorded.env_kwargs.items() if v is not None} == {"obs_type": "state", **family}
        assert envs_as_trained(recorded, env_id, {"obs_type": "state"}) == [{"obs_type": "state"}]
    scaled = RunFolder.at(tmp_path, "sac", "SGFD/MT-cheetah-run-v0", 2)
    scaled.record_start({"env_kwargs": {"robots": "scaled"}}, {}, None, step=0)
    assert RunFolder(scaled.path).args["env_family"] == {"robots": "scaled"}


def test_enjoy_record_video_and_the_hub_play_a_run_of_version_0_1_0_on_its_family(tmp_path):
    # The agent the trained-run commands choose takes its env settings from the run folder, as evaluate does: an
    # earlier run is played on the scaled robots it trained on, and the command line's settings go on top.
    from sgfd_zoo.enjoy import enjoy_parser
    from sgfd_zoo.trained import find_agent

    run = legacy_run(tmp_path)
    args = enjoy_parser().parse_args(["--env", run.env_id, "-f", str(tmp_path / "logs"), "--load-last-checkpoint"])
    assert (
        find_agent(args).env_kwargs
        == run.env_kwargs
        == {
            "obs_type": "state",
            "observe_parameter": True,
            "robots": "scaled",
        }
    )
    args = enjoy_parser().parse_args(["--env", run.env_id, "-f", str(tmp_path / "logs"), "--split", "interpolation"])
    args.load_last_checkpoint = True
    assert find_agent(args).env_kwargs == {**run.env_kwargs, "split": "interpolation"}
