"""Small files, huge costs (docs/trust.md, "Limits"): each hostile input of the audit is built here, small, and given
to the real command or reader. Each is refused in one line naming the file, the limit and the value, before the
cost is paid: the value the refusal names is near the limit (the reading stopped there), the memory it took is a
few megabytes (tracemalloc), and nothing of the size the input declares is ever allocated."""

from __future__ import annotations

import io
import json
import os
import struct
import subprocess
import sys
import tracemalloc
import zipfile
import zlib
from pathlib import Path

import numpy as np
import pytest

import sgfd_envs
from sgfd_envs import limits as env_limits
from sgfd_zoo.runs import bounded
from sgfd_zoo.runs.bounded import LIMITS, RefusedFile
from sgfd_zoo.runs.safe import load_yaml
from tests.zoo.test_trust import make_run, refused, write_record, write_spec
from tests.zoo.zoo_runs import ENV_ID, NAME

REPO = Path(__file__).resolve().parents[2]


def billion_laughs(key: str) -> str:
    """A 1 kB spec whose ``key`` expands, alias by alias, to 9**9 strings."""
    lines = ["name: s", "algos: [sgfd_sac]", f"envs: [{ENV_ID}]"]
    lines.append("seeds: [0]" if key != "seeds" else "seeds: &a0 [0, 0, 0, 0, 0, 0, 0, 0, 0]")
    if key == "train":
        lines.append('laughs: &a0 ["--quick", "--quick", "--quick", "--quick", "--quick", "--quick", "--quick"]')
    for depth in range(1, 9):
        lines.append(f"l{depth}: &a{depth} [{', '.join([f'*a{depth - 1}'] * 9)}]")
    lines.append(f"{key}: *a8")
    return "\n".join(lines) + "\n"


def peak_bytes(call) -> int:
    """The most memory ``call()`` held at once (it may raise)."""
    tracemalloc.start()
    try:
        call()
    except Exception:
        pass
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    return peak


def limit_value(line: str, name: str) -> int:
    """The value a refusal names for the limit ``name`` (``... is 10008, over the limit NAME = ...``)."""
    assert f"over the limit {name} = {LIMITS.get(name, '')}" in line, line
    return int(line.split(", over the limit")[0].rsplit(" ", 1)[1])


# -- YAML ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("key", ["seeds", "train"])
def test_a_billion_laughs_spec_is_refused_at_its_first_oversized_alias(tmp_path: Path, key: str) -> None:
    spec = tmp_path / "studies" / "s" / "spec.yml"
    spec.parent.mkdir(parents=True)
    spec.write_text(billion_laughs(key))
    assert len(spec.read_bytes()) < 1500
    line = refused(["study", spec, "--plan"], f"SPEC {spec}: refused", "MAX_YAML_NODES")
    assert limit_value(line, "MAX_YAML_NODES") < 2 * LIMITS["MAX_YAML_NODES"]  # stopped there, not at 9**9
    assert peak_bytes(lambda: load_yaml(spec.read_text(), spec)) < 8 * 2**20


def test_a_yaml_document_that_contains_itself_is_refused(tmp_path: Path) -> None:
    with pytest.raises(RefusedFile, match="an alias inside its own anchor"):
        load_yaml("seeds: &loop [0, *loop]\n", tmp_path / "spec.yml")


@pytest.mark.parametrize(
    ("config", "limit"),
    [
        ("a:\n" + "".join("  " * depth + f"k{depth}:\n" for depth in range(1, 200)), "MAX_YAML_DEPTH"),
        ("[" * 3000 + "]" * 3000 + "\n", "MAX_YAML_DEPTH"),  # flow style: no recursion either
        ("x: " + "y" * (5 * 2**20) + "\n", "MAX_YAML_BYTES"),  # the audit's 5 MB config.yml
    ],
    ids=["block-nesting", "flow-nesting", "5-MB"],
)
def test_a_records_yaml_over_a_limit_is_refused_in_one_line(tmp_path: Path, config: str, limit: str) -> None:
    study = tmp_path / "studies" / "s"
    record = write_record(study, config=config)
    line = refused(["study", write_spec(study), "-f", tmp_path / "logs", "--export-only"], str(record / "config.yml"))
    assert limit_value(line, limit) <= max(LIMITS[limit] + 1, len(config.encode()))
    assert not (study / "results.md").exists()


# -- JSON ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "named"),
    [
        ('{"num_timesteps": 1e999, "model": {}}', "the number 1e999, which is not finite"),
        ('{"num_timesteps": NaN, "model": {}}', "NaN, which is not a finite number"),
        ("[" * 3000 + "]" * 3000, "over the limit MAX_JSON_DEPTH = 64"),
    ],
    ids=["1e999", "NaN", "3000-deep"],
)
def test_a_json_file_with_a_number_that_is_not_finite_or_too_deep_is_refused(
    tmp_path: Path, text: str, named: str
) -> None:
    logs = tmp_path / "logs"
    run = make_run(logs)
    (run / "finished.json").write_text(text)
    refused(["evaluate", "-f", logs], str(run / "finished.json"), named)


# -- CSV ----------------------------------------------------------------------------------------------------


def test_a_csv_field_over_its_limit_is_refused_in_one_line(tmp_path: Path) -> None:
    study = tmp_path / "studies" / "s"
    record = write_record(study)
    field = "9" * (LIMITS["MAX_CSV_FIELD_BYTES"] + 10)
    (record / "diagnostics.csv").write_text(f"timesteps,sgfd/classifier_accuracy\n1000,{field}\n")
    line = refused(["study", write_spec(study), "-f", tmp_path / "logs", "--export-only"], "diagnostics.csv")
    assert "MAX_CSV_FIELD_BYTES = 131072" in line


def test_a_csv_file_over_its_limit_is_refused_before_a_row_is_read(tmp_path: Path) -> None:
    path = tmp_path / "progress.csv"
    with path.open("wb") as handle:  # sparse: 17 MB on paper, nothing on the disk
        handle.write(b"time/total_timesteps,x\n")
        handle.truncate(LIMITS["MAX_CSV_BYTES"] + 2**20)
    with pytest.raises(RefusedFile, match="over the limit MAX_CSV_BYTES"):
        bounded.read_csv(path)


# -- npz and zip --------------------------------------------------------------------------------------------


def declare_inflated(path: Path, member: str, size: int) -> None:
    """Make zip ``path`` declare ``size`` inflated bytes for ``member``, in its local header and its central
    directory, as a deflated bomb does: zipfile never inflates more than a member declares, so a reader that
    trusts the declaration pays for ``size``."""
    data = bytearray(path.read_bytes())
    with zipfile.ZipFile(path) as archive:
        info = archive.getinfo(member)
    struct.pack_into("<I", data, info.header_offset + 22, size)  # the local header's uncompressed size
    start = data.find(b"PK\x01\x02")  # the central directory's entries
    while start != -1:
        name_length = struct.unpack_from("<H", data, start + 28)[0]
        if data[start + 46 : start + 46 + name_length].decode() == member:
            struct.pack_into("<I", data, start + 24, size)
        start = data.find(b"PK\x01\x02", start + 46 + name_length)
    path.write_bytes(bytes(data))


@pytest.mark.parametrize(("declared", "limit"), [(2**31, "MAX_NPZ_BYTES"), (100 * 2**20, "MAX_ARRAY_BYTES")])
def test_an_npz_member_declaring_gigabytes_is_refused_before_it_is_inflated(
    tmp_path: Path, declared: int, limit: str
) -> None:
    logs = tmp_path / "logs"
    run = make_run(logs)
    path = run / "evaluations_train.npz"
    np.savez_compressed(path, timesteps=np.arange(4), results=np.zeros((4, 2)))
    declare_inflated(path, "results.npy", declared)
    line = refused(["plot", "-f", logs], str(path), limit)
    assert limit_value(line, limit) >= declared
    assert peak_bytes(lambda: bounded.load_npz(path)) < 8 * 2**20


def test_an_npy_header_declaring_more_than_its_member_holds_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "evaluations_train.npz"
    header = {"descr": "<f8", "fortran_order": False, "shape": (2**37,)}  # 2**40 bytes, declared in 1 kB
    buffer = io.BytesIO()
    np.lib.format.write_array_header_1_0(buffer, header)
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("results.npy", buffer.getvalue() + bytes(1024))
    with pytest.raises(bounded.UnreadableFile, match="declares 1099511627776 bytes, its member holds"):
        bounded.load_npz(path)
    assert peak_bytes(lambda: bounded.load_npz(path)) < 8 * 2**20


def test_an_npz_file_over_its_limit_is_refused_before_it_is_opened(tmp_path: Path) -> None:
    path = tmp_path / "evaluations_train.npz"
    with path.open("wb") as handle:  # sparse
        handle.truncate(LIMITS["MAX_NPZ_FILE_BYTES"] + 1)
    with pytest.raises(RefusedFile, match="over the limit MAX_NPZ_FILE_BYTES"):
        bounded.load_npz(path)


def test_a_model_zips_data_member_declaring_two_gigabytes_is_never_inflated(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    run = make_run(logs)
    np.savez(run / "evaluations_train.npz", timesteps=np.array([100]), results=np.ones((1, 2)))
    model = run / f"{NAME}.zip"  # a final model without finished.json: its step counts are read from it
    with zipfile.ZipFile(model, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("data", json.dumps({"num_timesteps": 100, "_total_timesteps": 100}) + " " * 4096)
    declare_inflated(model, "data", 2**31)
    code, out, err = zoo_plot(logs)  # plot loads no model and reads no model's data
    assert code == 0 and "Wrote" in out, err
    refused(["evaluate", "-f", logs], f"{model} (member data)", "MAX_ZIP_MEMBER_BYTES = 16777216")


def zoo_plot(logs: Path) -> tuple[int, str, list[str]]:
    from tests.zoo.zoo_runs import zoo

    return zoo(["plot", "-f", str(logs)])


def test_a_fifo_where_a_file_should_be_is_refused_without_blocking(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    run = make_run(logs)
    (run / NAME / "args.yml").unlink()
    os.mkfifo(run / NAME / "args.yml")  # opened for reading, it would wait for a writer forever
    probe = f"from pathlib import Path; from sgfd_zoo.runs.folders import RunFolder; RunFolder(Path({str(run)!r})).args"
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=300)
    assert done.returncode != 0 and "not a regular file" in done.stderr.splitlines()[-1]


# -- images -------------------------------------------------------------------------------------------------


def png_header(side: int) -> bytes:
    """The first chunk of a side x side PNG (its IHDR, as a 16000 x 16000 image starts), then its end: what a
    reader knows of an image's size before it decodes anything."""

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    ihdr = struct.pack(">IIBBBBB", side, side, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IEND", b"")


def test_an_image_size_over_its_limit_is_refused_in_one_line(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="image_size 20000 is over the limit MAX_IMAGE_SIZE = 1024"):
        sgfd_envs.make_domain_vec_env("SGFD/walker-walk-v0", image_size=20000)
    logs = tmp_path / "logs"
    argv = ["train", "--algo", "sac", "--env", ENV_ID, "--quick", "-f", logs, "--env-kwargs", "image_size:20000"]
    refused(argv, "image_size 20000 is over the limit MAX_IMAGE_SIZE")


def test_background_images_over_their_pixel_limit_are_refused_before_they_are_decoded(tmp_path: Path) -> None:
    folder = tmp_path / "backgrounds"
    folder.mkdir()
    for index in range(5):  # five 16000 x 16000 PNGs (their headers: 60 bytes each)
        (folder / f"image{index}.png").write_bytes(png_header(16000))
    with pytest.raises(ValueError, match=r"image0.png' is 256000000 pixels, over the limit MAX_BACKGROUND_PIXELS"):
        sgfd_envs.make_domain_vec_env("SGFD/walker-walk-v0", background_dir=str(folder), image_size=16)
    (folder / "image0.png").write_bytes(png_header(8192))  # over the zoo's limit, under Pillow's own
    with pytest.raises(ValueError, match=r"is 8192 x 8192 = 67108864 pixels, over the limit MAX_BACKGROUND_PIXELS"):
        sgfd_envs.make_domain_vec_env("SGFD/walker-walk-v0", background_dir=str(folder), image_size=16)
    # One within the limit is read on, to OpenCV (which finds a header and no pixels).
    (folder / "image0.png").write_bytes(png_header(4096))
    env_limits.check_image_file(folder / "image0.png", "background_dir")
    from sgfd_envs.backgrounds import ImageBackground

    with pytest.raises(ValueError, match="OpenCV could not read the image"):
        ImageBackground(folder / "image0.png", 16, 16)


# -- the page -----------------------------------------------------------------------------------------------


def test_every_limit_is_on_the_trust_page_with_its_value() -> None:
    page = (REPO / "docs" / "trust.md").read_text()
    named = {**LIMITS, **{k: v for k, v in vars(env_limits).items() if k.startswith("MAX_") and isinstance(v, int)}}
    assert len(named) >= 16
    for name, value in named.items():
        assert f"| `{name}` | {value} |" in page, name
