"""The zoo's command line: every rl-zoo3 option read by the zoo itself (no sys.argv handed to rl-zoo3), no
abbreviation taken, help without markup, tracking that names its install, and the runs' names in TensorBoard."""

from __future__ import annotations

import ast
import contextlib
import inspect
import io
import re
from pathlib import Path

import pytest

from sgfd_cli import COMMANDS
from sgfd_cli import main as zoo_main
from sgfd_zoo.enjoy import enjoy_parser
from sgfd_zoo.train_options import train_parser
from tests.project.test_installs import run_without

ENV_ID = "SGFD/MT-walker-walk-v0"
# The zoo's defaults that differ from rl-zoo3's, and why: its own algorithms (rl-zoo3: ppo, CartPole-v1), a log
# folder of its own runs (rl-zoo3's enjoy: its downloaded agents), a fifth of the run between checkpoints (rl-zoo3:
# none); -n is the yaml's in both (rl-zoo3's train: -1; the zoo's: -1 too).
OWN_DEFAULTS = {"algo", "env", "save_freq", "folder"}


def rl_zoo3_options(function) -> dict[str, tuple[tuple[str, ...], object]]:
    """The options rl-zoo3's script ``function`` defines, read from its source: dest -> (flags, default)."""
    tree = ast.parse(inspect.getsource(function))
    options = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, "attr", "") == "add_argument":
            flags = tuple(arg.value for arg in node.args if isinstance(arg, ast.Constant))
            keywords = {keyword.arg: keyword.value for keyword in node.keywords}
            default = ast.literal_eval(keywords["default"]) if "default" in keywords else None
            action = keywords.get("action")
            if isinstance(action, ast.Constant) and action.value == "store_true":
                default = default or False
            long_flag = next((flag for flag in flags if flag.startswith("--")), flags[0])
            options[long_flag.lstrip("-").replace("-", "_")] = (flags, default)
    return options


@pytest.mark.parametrize("script", ["train", "enjoy"])
def test_every_rl_zoo3_option_is_read_by_the_zoo_under_its_name_and_default(script: str) -> None:
    import rl_zoo3.enjoy
    import rl_zoo3.train

    theirs = rl_zoo3_options(rl_zoo3.train.train if script == "train" else rl_zoo3.enjoy.enjoy)
    assert len(theirs) > (40 if script == "train" else 20)
    parser = train_parser("sgfd-zoo train") if script == "train" else enjoy_parser()
    help_text = parser.format_help()
    ours = vars(parser.parse_args(["--env", ENV_ID]))
    for dest, (flags, default) in theirs.items():
        assert dest in ours, f"rl-zoo3's {flags} is not an option of sgfd-zoo {script}"
        assert all(re.search(rf"(^|[\s\[,]){re.escape(flag)}[\s\],]", help_text, re.M) for flag in flags), flags
        if dest not in OWN_DEFAULTS:
            assert ours[dest] == default, (flags, ours[dest], default)


@pytest.mark.parametrize(
    "argv",
    [
        ["train", "--qui", "-n", "100"],  # would be --quick for the zoo, unknown to rl-zoo3
        ["train", "--quick", "--seed", "0", "--eval-freq", "100", "--save-rep"],
        ["optimize", "--quick", "--n-trial", "2"],
        ["enjoy", "--no-rend"],
        ["record-video", "--split", "train", "--n-time", "5"],
        ["evaluate", "-f", "logs", "--n-ep", "1"],
    ],
)
def test_an_abbreviation_is_refused_in_one_line_and_nothing_starts(
    argv: list[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)  # where the default log folder would be made
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        assert zoo_main([*argv[:1], "--env", ENV_ID, *argv[1:]] if argv[0] != "evaluate" else argv) == 2
    lines = err.getvalue().strip().splitlines()
    given = [arg for arg in argv if arg.startswith("--")][-1]
    assert len(lines) == 1 and f"unrecognized arguments: {given}" in lines[0], lines
    assert "whole name" in lines[0] and not list(tmp_path.iterdir())


@pytest.mark.parametrize("command", list(COMMANDS))
def test_every_commands_help_is_plain_text(command: str) -> None:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.suppress(SystemExit):
        assert zoo_main([command, "-h"]) in (0, None)
    text = out.getvalue()
    assert text.startswith(f"usage: sgfd-zoo {command}"), text[:200]
    assert "``" not in text and not re.search(r":[a-z]+:`", text), text


@pytest.mark.parametrize(("flag", "missing"), [("-tb", "tensorboard"), ("--track", "wandb")])
def test_tracking_without_its_package_names_the_extra_in_one_line_and_makes_no_run_folder(
    flag: str, missing: str, tmp_path: Path
) -> None:
    argv = ["train", "--algo", "sac", "--env", ENV_ID, "--quick", "-n", "100", "-f", str(tmp_path / "logs"), flag]
    argv += [str(tmp_path / "tb")] if flag == "-tb" else []
    result = run_without({missing}, "import sys; from sgfd_cli import main; sys.exit(main(sys.argv[1:]))", *argv)
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2 and len(lines) == 1, result.stderr[-2000:]
    assert lines[0] == (
        f"sgfd-zoo train: error: {flag} needs {missing}, which the track extra brings: from the clone's root, "
        "pip install -e '.[track]' -c constraints.txt"
    )
    assert not (tmp_path / "logs").exists() and not (tmp_path / "tb").exists()


# Every agent logs under its own name: SB3's SAC.learn names its runs "SAC" (tb_log_name), whatever subclass learns.
AGENT_NAMES = {"sgfd_sac": "SGFD_SAC", "ambs": "AMBS", "dbc": "DBC", "ted": "TED", "sgqn": "SGQN", "sac": "SAC"}


@pytest.mark.slow
def test_each_agent_trained_by_the_zoo_logs_to_tensorboard_under_its_own_name(tmp_path: Path) -> None:
    tiny = ["--quick", "-n", "8", "--eval-freq", "-1", "--num-threads", "1", "--no-progress", "--verbose", "0"]
    tiny += ["-params", "learning_starts:1000", "buffer_size:100"]
    for algo in AGENT_NAMES:
        argv = ["train", "--algo", algo, "--env", ENV_ID, "-f", str(tmp_path / "logs"), "-tb", str(tmp_path / "tb")]
        assert zoo_main([*argv, *tiny]) == 0
    # rl-zoo3's layout: <tb>/<EnvName>/<name>_<n>; the zoo passes no tb_log_name, so each agent's own is used
    runs = sorted(path.name for path in (tmp_path / "tb" / "SGFD-MT-walker-walk-v0").iterdir())
    assert runs == sorted(f"{name}_1" for name in AGENT_NAMES.values())
