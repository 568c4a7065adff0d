"""The loaders' small files are read at the edge: KITTI calib.txt and times.txt, EuRoC sensor.yaml and data.csv,
the stereo folder's calibration.yaml and times.txt. Whatever they hold (any YAML structure, extreme numbers,
deep nesting, duplicate keys, aliases standing for billions of values, random bytes, a valid file mangled),
the reader returns or raises one `DatasetError` line naming the file; never another exception and never a
NumPy overflow warning (the test suite turns warnings into errors)."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest
import yaml
from hippo_nav.cli import main
from hippo_nav.datasets.common import read_yaml, yaml_number, yaml_numbers
from hippo_nav.datasets.euroc import CameraFiles
from hippo_nav.datasets.folder import read_times_file
from hippo_nav.datasets.kitti import read_calibration, read_times
from hippo_nav.io import DatasetError
from hypothesis import example, given, settings
from hypothesis import strategies as st

SETTINGS = settings(max_examples=60, deadline=None)

P0 = "P0: 7.188560e+02 0 6.071928e+02 0 0 7.188560e+02 1.852157e+02 0 0 0 1 0"
P1 = "P1: 7.188560e+02 0 6.071928e+02 -3.861448e+02 0 7.188560e+02 1.852157e+02 0 0 0 1 0"
KITTI_SIZE = (1241, 376)
SENSOR = """%YAML:1.0
camera_model: pinhole
intrinsics: [458.654, 457.296, 367.215, 248.375]
distortion_model: radial-tangential
distortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
T_BS:
  cols: 4
  rows: 4
  data: [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]
resolution: [752, 480]
"""

TOKENS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(min_value=-(10**400), max_value=10**400).map(str),
    st.sampled_from(
        ["nan", "inf", "1e308", "-1e308", "1e-308", "0", "1", "-1", "x", ":", "#", "[", "]", "*a"]
    ),
    st.text(alphabet=st.characters(blacklist_categories=("Cs",)), max_size=6),
)
SCALARS = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(10**400), max_value=10**400),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=10),
)
STRUCTURES = st.recursive(
    SCALARS,
    lambda children: st.one_of(
        st.lists(children, max_size=5), st.dictionaries(st.text(max_size=8), children, max_size=5)
    ),
    max_leaves=20,
)


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("calibration")


def _refused_in_one_line(call, path: Path) -> None:
    """Run `call()`; a refusal must be one `DatasetError` line naming `path`."""
    try:
        call()
    except DatasetError as err:
        message = str(err)
        assert "\n" not in message and str(path) in message, message
        assert len(message) < 1000, message[:200]


def _write(path: Path, text: str | bytes) -> Path:
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text, encoding="utf-8")
    return path


def _mutate(text: str, data: st.DataObject) -> str:
    """`text` with one of its whitespace-separated fields replaced, dropped or doubled, or the text cut."""
    fields = text.split(" ")
    at = data.draw(st.integers(min_value=0, max_value=len(fields) - 1))
    action = data.draw(st.sampled_from(["replace", "drop", "double", "cut"]))
    if action == "replace":
        fields[at] = data.draw(TOKENS)
    elif action == "drop":
        del fields[at]
    elif action == "double":
        fields.insert(at, fields[at])
    else:
        return text[: len(text) * at // len(fields)]
    return " ".join(fields)


@given(data=st.data())
@SETTINGS
def test_kitti_calibration_mutated_is_read_or_one_line(folder, data):
    text = _mutate(f"{P0}\n{P1}\nP2: {P0[4:]}\nP3: {P1[4:]}\n", data)
    path = _write(folder / "calib.txt", text)
    cameras = data.draw(st.sampled_from(["gray", "color"]))
    _refused_in_one_line(lambda: read_calibration(path, KITTI_SIZE, cameras), path)


@given(data=st.binary(max_size=300))
@SETTINGS
def test_kitti_calibration_random_bytes_are_one_line(folder, data):
    path = _write(folder / "calib.txt", data)
    _refused_in_one_line(lambda: read_calibration(path, KITTI_SIZE), path)


@given(lines=st.lists(st.lists(TOKENS, max_size=3).map(" ".join), max_size=6))
@SETTINGS
def test_timestamps_files_are_read_or_one_line(folder, lines):
    path = _write(folder / "times.txt", "\n".join(lines))
    _refused_in_one_line(lambda: read_times(path), path)
    _refused_in_one_line(lambda: read_times_file(path, len(lines)), path)


@given(data=STRUCTURES)
@example(data="\n")  # a value that is a line break: quoted escaped, the message stays one line
@SETTINGS
def test_any_yaml_structure_is_read_or_one_line(folder, data):
    path = _write(folder / "calibration.yaml", yaml.safe_dump({"fx": data, "K": data}))

    def read() -> None:
        values = read_yaml(path, "calibration")
        yaml_number(values, "fx", path)
        yaml_numbers(values, "K", path, 4, "a 2x2 matrix")
        yaml_numbers(values, "K", path, None, "any count")

    _refused_in_one_line(read, path)


@given(text=st.text(max_size=200))
@SETTINGS
def test_any_yaml_text_is_read_or_one_line(folder, text):
    path = _write(folder / "calibration.yaml", text)
    _refused_in_one_line(lambda: read_yaml(path, "calibration"), path)


@given(data=st.data())
@SETTINGS
def test_euroc_sensor_yaml_mutated_is_read_or_one_line(folder, data):
    camera = folder / "cam0"
    camera.mkdir(exist_ok=True)
    _write(camera / "data.csv", "#timestamp [ns],filename\n1403636579763555584,1403636579763555584.png\n")
    lines = SENSOR.splitlines()
    at = data.draw(st.integers(min_value=1, max_value=len(lines) - 1))
    key = lines[at].split(":")[0]
    lines[at] = data.draw(
        st.one_of(
            st.just(f"{key}: ").map(lambda head: head + data.draw(TOKENS)),
            STRUCTURES.map(lambda value: f"{key}: {yaml.safe_dump(value, default_flow_style=True).strip()}"),
            st.just(_mutate(lines[at], data)),
        )
    )
    path = _write(camera / "sensor.yaml", "\n".join(lines) + "\n")
    _refused_in_one_line(lambda: CameraFiles(camera), path)


@given(lines=st.lists(st.lists(TOKENS, max_size=3).map(",".join), max_size=5))
@SETTINGS
def test_euroc_image_list_is_read_or_one_line(folder, lines):
    path = _write(folder / "data.csv", "\n".join(lines))
    _refused_in_one_line(lambda: CameraFiles._read_list(path), path)


ALIAS_BOMB = "a: &a [1.0, 2.0]\n" + "".join(
    f"{chr(98 + k)}: &{chr(98 + k)} [{', '.join([f'*{chr(97 + k)}'] * 9)}]\n" for k in range(12)
) + "K: *m\nfx: *m\n"  # fmt: skip


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("K: " + "[" * 5000 + "]" * 5000, "nested too deeply"),
        ("fx: 1" + "0" * 5000, ":1: not valid YAML (cannot read this int"),
        ("fx: 2001-13-45\n", ":1: not valid YAML (cannot read this timestamp: month must be in 1..12)"),
        ("fx: 1.0\nfx: 2.0\n", ":2: not valid YAML (key 'fx' appears twice; keep one)"),
        (ALIAS_BOMB, "'K' holds more than 4 numbers"),
        ("fx: true\nK: [1, 2, 3, 4]\n", "'fx: True' is not a number"),
    ],
)
def test_malformed_yaml_is_one_line_saying_what_to_fix(folder, text, says):
    path = _write(folder / "calibration.yaml", text)
    with pytest.raises(DatasetError) as info:
        values = read_yaml(path, "calibration")
        yaml_numbers(values, "K", path, 4, "a 2x2 matrix")
        yaml_number(values, "fx", path)
    assert says in str(info.value) and str(info.value).startswith(str(path))


@pytest.mark.parametrize(
    ("replace", "by", "says"),
    [
        ("data: [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,", "data: [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,", "T_BS's upper-left 3x3 block is not a rotation"),
        ("[752, 480]", "[752.5, 480]", "must be whole pixels"),
        ("[752, 480]", "[1.0e300, 480]", "must be whole pixels"),
        ("camera_model: pinhole", "camera_model: [pinhole]", "'camera_model' must be a name (text), not a list"),
    ],
)  # fmt: skip
def test_malformed_sensor_yaml_is_one_line(folder, replace, by, says):
    camera = folder / "cam_bad"
    camera.mkdir(exist_ok=True)
    _write(camera / "data.csv", "1,a.png\n")
    path = _write(camera / "sensor.yaml", SENSOR.replace(replace, by))
    with pytest.raises(DatasetError, match=re.escape(says)) as info:
        CameraFiles(camera)
    assert str(info.value).startswith(str(path))


@pytest.mark.parametrize(
    ("text", "says"),
    [
        (f"{P0}\n{P1}\n{P0}\n", ":3: a second P0 line"),
        (P0.replace("7.188560e+02 0 6", "1e-308 0 6") + "\n" + P1.replace("7.188560e+02 0 6", "1e-308 0 6"), "fx = 1e-308"),
        (P0.replace("0 0 0 1 0", "0 1 0 1 0") + f"\n{P1}\n", "P[1,0], P[2,0] and P[2,1] must be 0"),
        (f"{P0}\n" + P1.replace("-3.861448e+02", "-1" + "0" * 5000), "NaN or infinity: -100000"),
    ],
)  # fmt: skip
def test_malformed_kitti_calibration_is_one_line(folder, text, says):
    path = _write(folder / "calib.txt", text)
    with pytest.raises(DatasetError, match=re.escape(says)) as info:
        read_calibration(path, KITTI_SIZE)
    assert len(str(info.value)) < 400


def test_huge_timestamps_are_one_line(folder):
    with pytest.raises(DatasetError, match=":2: timestamp 1e\\+308 is beyond"):
        read_times(_write(folder / "times.txt", "0\n1e308\n"))
    with pytest.raises(DatasetError, match=":1: timestamp '100000000000000000000000000000' is beyond int64"):
        CameraFiles._read_list(_write(folder / "data.csv", "1" + "0" * 29 + ",a.png\n"))


def test_a_folder_or_a_fifo_is_refused_without_waiting(tmp_path):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    for path in (tmp_path, fifo):
        with pytest.raises(DatasetError, match="folder|not a regular file"):
            read_calibration(path, KITTI_SIZE)
        with pytest.raises(DatasetError, match="folder|not a regular file"):
            read_times(path)
        with pytest.raises(DatasetError, match="folder|not a regular file"):
            read_yaml(path, "calibration")


def test_the_command_line_reports_a_bad_calibration_in_one_line(tmp_path, capsys):
    dataset = tmp_path / "pairs"
    for side in ("left", "right"):
        (dataset / side).mkdir(parents=True)
        (dataset / side / "1.png").write_bytes(b"not decoded before the calibration is read")
    calibration = _write(dataset / "calibration.yaml", "fx: 1.0\nfx: 2.0\n")
    assert main(["run", "--dataset", str(dataset), "--out", str(tmp_path / "run"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"hippo-nav: error: {calibration}:2: not valid YAML (key 'fx' appears twice; keep one)"
