"""The documentation's copies of figures stay equal to their sources: the study plots and tables shown on
docs/reproducing.md are the studies' exported ones, the cost of the paper's tables there is what `sgfd-zoo study
--plan` prints, and docs/agents.md's table of the two readings' defaults is what SGFDSettings gives."""

from __future__ import annotations

import json
import re
from dataclasses import fields
from decimal import ROUND_HALF_UP, Decimal
from pathlib import Path

import pytest
import yaml

from sb3_sgfd.sgfd.settings import SGFDSettings

REPO = Path(__file__).resolve().parents[2]
DOCS = REPO / "docs"
STUDIES = ("mt-state", "sgfd-strength")


def markdown_tables(text: str) -> list[list[list[str]]]:
    """Every pipe table of ``text``: its rows (the header first, the separator left out), each a list of cells."""
    tables: list[list[list[str]]] = []
    current: list[list[str]] = []
    for line in [*text.splitlines(), ""]:
        if line.startswith("|"):
            cells = [
                cell.strip() for cell in re.split(r"(?<!\\)\|", line.strip().removeprefix("|").removesuffix("|"))
            ]  # "\|" stays in a cell
            if not all(set(cell) <= set("-: ") for cell in cells):
                current.append(cells)
        elif current:
            tables.append(current)
            current = []
    return tables


def section(text: str, heading: str) -> str:
    """The text of the ``## `` section whose heading contains ``heading``, up to the next one."""
    parts = re.split(r"^## ", text, flags=re.MULTILINE)
    (match,) = [part for part in parts if heading in part.splitlines()[0]]
    return match


def aggregate(study: str) -> dict[str, list[list[str]]]:
    """The study's aggregate.md: per split, its table (the header, then algo, runs per task, IQM, mean, gap and
    the probability of improvement per algorithm)."""
    text = (REPO / "studies" / study / "aggregate.md").read_text()
    splits = re.findall(r"^# (\w+):", text, flags=re.MULTILINE)
    tables = markdown_tables(text)
    assert len(splits) == len(tables) == 3, (splits, len(tables))
    return dict(zip(splits, tables, strict=True))


def two_decimals(cell: str) -> str:
    """``0.467 [0.253, 0.667]`` as the docs round it: ``0.47 [0.25, 0.67]``."""
    return re.sub(r"\d+\.\d+", lambda m: str(Decimal(m.group()).quantize(Decimal("0.01"), ROUND_HALF_UP)), cell)


@pytest.mark.parametrize("study", STUDIES)
def test_the_sites_study_figure_is_the_studys_plot(study: str) -> None:
    shown = DOCS / f"study-{study}-extrapolation.png"
    exported = REPO / "studies" / study / "plots" / "aggregate_extrapolation.png"
    assert shown.read_bytes() == exported.read_bytes(), f"copy {exported} to {shown}"
    assert f"]({shown.name})" in (DOCS / "reproducing.md").read_text()


@pytest.mark.parametrize("study", STUDIES)
def test_the_reproducing_pages_iqm_table_is_the_studys_aggregate(study: str) -> None:
    text = section((DOCS / "reproducing.md").read_text(), f"`studies/{study}`")
    (table,) = [table for table in markdown_tables(text) if table[0][0] == "split"]
    tables = aggregate(study)
    algos = [row[0] for row in tables["train"][1:]]
    assert len(table[0]) == 1 + len(algos), (table[0], algos)
    shown_splits = []
    for label, *cells in table[1:]:
        if label.startswith("P("):
            # the probability of improvement, "P(DR > algo), extrapolation", rounded to two decimals on the page
            probability, split = label.split(", ")
            assert probability == tables[split][0][-1], (label, tables[split][0])
            expected = [two_decimals(row[-1]) for row in tables[split][1:]]
        else:
            shown_splits.append(label)
            expected = [row[2] for row in tables[label][1:]]
        assert cells == expected, (study, label, cells, expected)
    assert shown_splits == ["train", "interpolation", "extrapolation"]


def test_the_reproducing_pages_final_returns_are_the_strength_studys_results() -> None:
    text = section((DOCS / "reproducing.md").read_text(), "`studies/sgfd-strength`")
    (table,) = [table for table in markdown_tables(text) if table[0][0] == "task"]
    results = (REPO / "studies" / "sgfd-strength" / "results.md").read_text()
    extrapolation = results[results.index("# extrapolation") :]
    exported = {row[0]: row[1:] for row in markdown_tables(extrapolation)[0][1:]}
    assert len(table) - 1 == len(exported) - 1  # the export adds a total row
    for task, *cells in table[1:]:
        assert cells == exported[task], (task, cells, exported[task])


def test_the_reproducing_pages_table_cost_is_what_the_plan_prints(monkeypatch: pytest.MonkeyPatch) -> None:
    from sgfd_zoo.study import plan_lines, read_spec

    monkeypatch.chdir(REPO)  # the plan names the spec's folder as the command line gave it
    text = section((DOCS / "reproducing.md").read_text(), "At paper scale")
    shown = re.search(r"```text\n(.*?)\n```", text, flags=re.DOTALL)
    assert shown is not None
    spec = read_spec(Path("studies/paper-table1/spec.yml"))
    assert shown.group(1) == "\n".join(plan_lines(spec, Path("studies/paper-table1"), 1, None))
    # the wall time on 8 GPUs the page quotes
    (wall,) = [line for line in plan_lines(spec, Path("studies/paper-table1"), 8, None) if line.startswith("wall")]
    quoted = re.search(r"`--gpus 8` gives the wall\s+time on 8 such GPUs \(([\d.]+) h for the same (\d+) runs\)", text)
    assert quoted is not None and f"of those {quoted.group(2)} runs" in wall and f": {quoted.group(1)} h" in wall


def reading_value(cell: str) -> object:
    """A cell of the readings' table as a setting's value: its first word (``1e-3 Adam``: 1e-3, ``off``: None)."""
    word = cell.split()[0]
    named = {"off": None, "True": True, "False": False}
    return named[word] if word in named else float(word)


def test_the_agents_pages_reading_defaults_are_sgfd_settings() -> None:
    text = (DOCS / "agents.md").read_text()
    (table,) = [table for table in markdown_tables(text) if table[0] == ["argument", "paper", "official"]]
    paper, official = SGFDSettings.paper(), SGFDSettings.official()
    shown = {}
    for argument, paper_cell, official_cell in table[1:]:
        found = re.match(r"`(\w+)`", argument)
        assert found is not None, argument
        shown[found.group(1)] = (reading_value(paper_cell), reading_value(official_cell))
    for name, (paper_value, official_value) in shown.items():
        assert (paper_value, official_value) == (getattr(paper, name), getattr(official, name)), name
    # every setting where the readings differ is in the table, and no other
    differ = {f.name for f in fields(SGFDSettings) if getattr(paper, f.name) != getattr(official, f.name)} - {"reading"}
    assert set(shown) == differ, sorted(set(shown) ^ differ)
    # the settings the page lists as the same in both readings, with their value
    others = text[text.index("The others:") : text.index("### What it logs")]
    listed = dict(re.findall(r"`(\w+)` \(([^),]+)", others))
    for name, value in listed.items():
        if name in {f.name for f in fields(SGFDSettings)}:
            expected = None if value.split()[0] == "None" else float(value)
            assert getattr(paper, name) == getattr(official, name) == expected, (name, value)
    assert {"classifier_start", "classifier_hidden_dim", "n_rff", "reweight_momentum", "reweight_max_step"} <= set(
        listed
    )


def test_the_demo_draws_the_tasks_asked_for_and_names_a_domain() -> None:
    from sgfd_envs.demo import benchmark_observations, observe

    rows = benchmark_observations("DCS", steps=1, image_size=16, tasks=("reacher-easy",))
    assert [[(task, split) for task, split, _ in row] for row in rows] == [
        [("reacher-easy", split) for split in ("train", "easy", "medium", "hard")]
    ]
    assert all(pixels.shape == (16, 16, 3) for _, _, pixels in rows[0])
    with pytest.raises(ValueError, match=r"tasks must be tasks of DCS .*got \['walker-run'\]"):
        benchmark_observations("DCS", tasks=("walker-walk", "walker-run"))
    _, caption = observe("SGFD/MT-walker-walk-v0", "train", steps=1, image_size=16, domain=2)
    assert caption.startswith("train 2 s5 ")  # HiP-BMDP's files, the authors' training files 2, 3, 5, 6


def test_the_sites_front_page_shows_the_readmes_intro() -> None:
    import importlib.util

    spec = importlib.util.spec_from_file_location("docs_hooks", DOCS / "hooks.py")
    assert spec is not None and spec.loader is not None
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    page = hooks.on_page_markdown((DOCS / "index.md").read_text())
    assert "<!-- README:" not in page
    readme = (REPO / "README.md").read_text()
    first = next(line for line in readme.splitlines() if line.startswith("Saliency-Guided Features Decorrelation"))
    assert first in page and "](envs-overview.png)" in page and "](docs/" not in page
    with pytest.raises(ValueError, match=r"name must be a part of README\.md"):
        hooks.readme_part("outro", readme)


def test_the_api_pages_headings_are_import_paths_and_their_signatures_are_formatted() -> None:
    config = yaml.safe_load((REPO / "mkdocs.yml").read_text())
    (handler,) = [plugin["mkdocstrings"] for plugin in config["plugins"] if isinstance(plugin, dict)]
    options = handler["handlers"]["python"]["options"]
    assert options["show_root_full_path"] is True  # "sb3_sgfd.dbc.losses", not "losses"
    assert options["separate_signature"] is True and options["line_length"] <= 100
    # mkdocstrings wraps a signature only when Black or Ruff is installed: the docs extra brings Ruff
    (docs_extra,) = re.findall(r"^docs = \[(.*)\]$", (REPO / "pyproject.toml").read_text(), flags=re.MULTILINE)
    assert {'"ruff"', '"black"'} & {name.strip() for name in docs_extra.split(",")}, docs_extra


# -- figures measured by a committed command ----------------------------------------------------------------------
# A table whose first column, "record", links a json under docs/measured/ (written by the command's own --record)
# shows, in each other column, what that record says: the test knows how each column is read from a record.
MEASURED = DOCS / "measured"


def duration(seconds: float) -> str:
    """``754.2`` as ``12m34s``, as the examples and the quick job print times."""
    minutes, rest = divmod(round(seconds), 60)
    return f"{minutes}m{rest:02d}s" if minutes else f"{rest}s"


def record_cell(record: dict, column: str) -> str:
    """What a docs table shows in ``column`` for a record."""
    machine = record["machine"]
    if column == "command":
        words = record["command"].split()
        if "--record" in words:
            del words[words.index("--record") : words.index("--record") + 2]
        return f"`{' '.join(words)}`"
    if column == "date, machine":
        load = f"load {machine['load_1min']:.1f} → {record['load_1min_at_end']:.1f}"
        return f"{record['date']}, {machine['cpus']} cores ({machine['cpu']}), {load}"
    if column == "wall time":
        return duration(record["wall_seconds"])
    if column == "training per step":
        return f"{record['ms_per_step']:g} ms ({record['cpu_ms_per_step']:g} ms CPU)"
    if column == "evaluation":
        episodes = record["eval_episodes"]
        return f"{duration(record['eval_seconds'])} ({episodes} episode{'s' * (episodes != 1)} per split)"
    if column in record.get("returns", {}) and isinstance(record["returns"][column], list):
        mean, std = record["returns"][column]
        return f"{mean:.1f} ± {std:.1f}"
    if column.startswith("IQM "):
        value, low, high = record["iqm"][column.removeprefix("IQM ")]
        return f"{value:.3f} [{low:.3f}, {high:.3f}]"
    if column.startswith("P("):
        value, low, high = record["improvement"][column]
        return f"{value:.2f} [{low:.2f}, {high:.2f}]"
    if column == "SGFD's weights":
        weights = record["sgfd_weights"].values()
        first = min(run["first_step"] for run in weights)
        low, high = min(run["ess_min"] for run in weights), max(run["ess_max"] for run in weights)
        return f"ESS {low:.2f}-{high:.2f} n from step {first}"
    raise AssertionError(f"no rule for the column {column!r}")


def measured_tables(
    page: str, kinds: tuple[str, ...] = ("record", "earlier record")
) -> list[tuple[list[str], list[str]]]:
    """(header, row) of each row of ``page``'s tables whose first column is one of ``kinds`` (``record``: made with
    today's code; ``earlier record``: kept as it was made, by earlier code)."""
    rows = []
    for table in markdown_tables((DOCS / page).read_text()):
        if table[0][0] in kinds:
            rows += [(table[0], row) for row in table[1:]]
    return rows


def linked_record(cell: str) -> dict:
    found = re.fullmatch(r"\[[^]]+\]\(measured/([\w.-]+\.json)\)", cell)
    assert found is not None, f"the record column links a file under docs/measured/: {cell}"
    return json.loads((MEASURED / found.group(1)).read_text())


@pytest.mark.parametrize("page", ["examples.md", "getting-started.md"])
def test_the_figures_a_page_quotes_are_its_records(page: str) -> None:
    rows = measured_tables(page)
    assert rows, f"{page} has no table of measured figures"
    for header, (link, *cells) in rows:
        record = linked_record(link)
        for column, cell in zip(header[1:], cells, strict=True):
            assert cell == record_cell(record, column), (page, link, column)


def rows_in_order(shown: list[list[str]], printed: list[list[str]]) -> bool:
    """Whether every row of ``shown`` is a row of ``printed``, in the same order."""
    rest = iter(printed)
    return bool(shown) and all(row in rest for row in shown)


def bench_tables(page: str) -> list[tuple[str, list[list[str]]]]:
    """Every table of ``page`` that follows a link to a bench's record (``](measured/bench-NAME.txt)``) in its
    section, with that record's file name: the table is a copy of one the bench printed."""
    found = []
    for part in re.split(r"^#+ ", (DOCS / page).read_text(), flags=re.MULTILINE):
        blocks = re.split(r"(\]\(measured/bench-[\w.-]+\.txt\))", part)
        record = None
        for block in blocks:
            link = re.fullmatch(r"\]\(measured/(bench-[\w.-]+\.txt)\)", block)
            if link:
                record = link.group(1)
            elif record is not None:
                found += [(record, table) for table in markdown_tables(block)]
    return found


@pytest.mark.parametrize("page", ["performance.md", "papers-and-code.md", "benchmarks.md"])
def test_the_bench_tables_a_page_shows_are_the_benches_printed_ones(page: str) -> None:
    shown = bench_tables(page)
    assert shown, f"{page} shows no bench table with its record"
    for record, table in shown:
        text = (MEASURED / record).read_text()
        assert text.startswith("command: python bench/"), record
        # the same header and rows the bench printed, in its order; the page may leave rows out
        matches = [printed for printed in markdown_tables(text) if printed[0] == table[0]]
        assert any(rows_in_order(table[1:], printed[1:]) for printed in matches), (page, record, table[0])


def test_every_record_is_a_commands_output() -> None:
    """Each file under docs/measured/ names the command that wrote it, its date and the machine."""
    for path in MEASURED.iterdir():
        if path.suffix == ".json":
            record = json.loads(path.read_text())
            assert {"command", "date", "machine"} <= set(record), path.name
            assert record["command"].startswith(("python examples/", "sgfd-zoo quick")), path.name
        else:
            head = path.read_text().splitlines()[:4]
            assert [line.split(":")[0] for line in head] == [
                "command",
                "date",
                "machine at the start",
                "machine at the end",
            ]


def test_the_quick_jobs_printed_tables_on_getting_started_are_its_records() -> None:
    text = section((DOCS / "getting-started.md").read_text(), "Install and run the main job")
    after = text[text.index("What `sgfd-zoo quick --short` printed") :]
    printed = after[after.index("```\n") + 4 : after.index("\n```", after.index("```\n") + 4)]
    (_, (link, *_)), *_ = measured_tables("getting-started.md")  # the block is the first record's run
    record = linked_record(link)
    table_lines = [line for line in printed.splitlines() if line.startswith("|")]
    assert len(table_lines) >= 6
    exported = (record["results"] + record["aggregate"]).splitlines()
    assert all(line in exported for line in table_lines), [line for line in table_lines if line not in exported]
    # and the headings over them
    headings = [line for line in printed.splitlines() if line.startswith("# ")]
    assert headings and all(heading in exported for heading in headings)

    # the job is seeded: every run of the same command with today's code printed the same tables (at least two
    # runs of it are recorded, so that the comparison compares)
    def job(command: str) -> str:
        return re.sub(r" --record \S+", "", command)

    same = [
        linked_record(other)
        for _, (other, *_) in measured_tables("getting-started.md", kinds=("record",))
        if job(linked_record(other)["command"]) == job(record["command"])
    ]
    assert len(same) >= 2, "one run of the job recorded: nothing shows it is seeded"
    for again in same:
        assert (again["results"], again["aggregate"]) == (record["results"], record["aggregate"]), again["command"]
