"""The loader contract (`StereoLoader`): every registered loader follows it, the command line derives its
choices from the registry, and any dataset's optional attributes are read in one place with defaults."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest
from hippo_nav.cli import build_parser, main
from hippo_nav.datasets import (
    LOADERS,
    DatasetError,
    DatasetExtras,
    KittiOdometry,
    LoaderFlag,
    StereoFrame,
    StereoLoader,
    open_dataset,
)


def _run_options(parser: argparse.ArgumentParser, command: str = "run") -> dict[str, argparse.Action]:
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {flag: action for action in sub.choices[command]._actions for flag in action.option_strings}


def test_every_registered_loader_follows_the_contract():
    assert list(LOADERS) == ["kitti", "euroc", "rosbag", "folder"]  # the detection order
    for kind, loader in LOADERS.items():
        assert issubclass(loader, StereoLoader) and loader.KIND == kind
        assert {"start", "stop", "stride"} <= set(loader.OPTIONS)
        assert loader.TITLE and loader.LAYOUT.startswith("for ")
    assert LOADERS["kitti"].DEFAULT_SEQUENCE == "00"


def test_a_loader_has_the_extras_and_the_base_checks_its_index(rendered: KittiOdometry):
    extras = DatasetExtras.of(rendered)
    assert extras == DatasetExtras(
        note="", warnings=[], missing_frames=[], frames_without_timestamp=0, stride=1
    )
    assert rendered[-1].index == rendered.frame_indices[-1]
    with pytest.raises(IndexError, match="frame 12 out of range for a dataset of 12 frames"):
        _ = rendered[12]
    assert [f.index for f in rendered] == list(rendered.frame_indices)


def test_a_dataset_without_extras_gets_the_defaults():
    class Bare:
        pass

    assert DatasetExtras.of(Bare()) == DatasetExtras()


def test_the_command_line_derives_its_choices_from_the_registry(monkeypatch, tmp_path: Path, capsys):
    class Dummy(KittiOdometry):
        KIND, TITLE, LAYOUT = "dummy", "dummy datasets", "for a dummy the folder"
        OPTIONS = ("start", "stop", "stride", "left_topic")

        @staticmethod
        def detect(path: Path) -> bool:
            return path.name == "dummy"

    options = _run_options(build_parser())
    assert options["--dataset-kind"].choices == list(LOADERS)
    assert options["--kitti"] is options["--dataset"]  # one option, two spellings
    assert options["--lesion"].choices == ["ventral", "intermediate", "dorsal"]
    monkeypatch.setitem(LOADERS, "dummy", Dummy)
    options = _run_options(build_parser())
    assert "dummy" in options["--dataset-kind"].choices
    assert options["--left-topic"].help.startswith("rosbag/dummy:")
    # A loader option is refused for a kind whose contract does not take it, naming the kinds that do.
    folder = tmp_path / "dummy"
    folder.mkdir()
    assert main(["run", "--dataset", str(folder), "--dataset-kind", "folder", "--left-topic", "/l"]) == 2
    assert "--left-topic: only for ROS bags or dummy datasets" in capsys.readouterr().err


def test_a_loaders_declared_flags_become_run_and_sweep_options(monkeypatch, tmp_path: Path, capsys):
    """A loader that declares `FLAGS` gets them as `run` and `sweep` flags and sweep-file keys, with no
    change to the command line: the option reaches the loader's constructor."""
    opened_with: list[str | None] = []

    class Exposed(StereoLoader):
        KIND, TITLE, LAYOUT = "exposed", "exposed datasets", "for an exposed dataset the folder"
        OPTIONS = ("start", "stop", "stride", "exposure_ms")
        FLAGS = (LoaderFlag("exposure_ms", "MS", "exposure time (default: the camera's)"),)

        def __init__(self, root, sequence, start=None, stop=None, stride=1, exposure_ms=None) -> None:
            super().__init__(stride)
            opened_with.append(exposure_ms)
            raise DatasetError(f"{root}: opened with exposure_ms={exposure_ms}")

        @staticmethod
        def detect(path: Path) -> bool:
            return path.name == "exposed"

        def _frame(self, i: int) -> StereoFrame:
            raise AssertionError("never read")

    for loader in LOADERS.values():  # the contract: a loader's flags are among its options
        assert {flag.keyword for flag in loader.FLAGS} <= set(loader.OPTIONS), loader.KIND
    assert LoaderFlag("left_topic", "TOPIC", "").flag == "--left-topic"
    monkeypatch.setitem(LOADERS, "exposed", Exposed)
    parser = build_parser()
    for command in ("run", "sweep"):
        action = _run_options(parser, command)["--exposure-ms"]
        assert (action.dest, action.metavar) == ("exposure_ms", "MS")
        assert action.help == "exposed: exposure time (default: the camera's)"
    folder = tmp_path / "exposed"
    folder.mkdir()
    # run: the flag reaches the loader, and is refused for a kind that does not take it.
    assert main(["run", "--dataset", str(folder), "--exposure-ms", "4", "--out", str(tmp_path / "r")]) == 2
    assert opened_with == ["4"] and "opened with exposure_ms=4" in capsys.readouterr().err
    assert main(["run", "--dataset", str(folder), "--dataset-kind", "folder", "--exposure-ms", "4"]) == 2
    assert "--exposure-ms: only for exposed datasets; " in capsys.readouterr().err
    # sweep: the flag and a sweep file's key of the same name reach every run's dataset input.
    import hippo_nav.sweep

    spaces = []
    build_space = hippo_nav.sweep.build_space
    monkeypatch.setattr(
        hippo_nav.sweep, "build_space", lambda *a, **kw: spaces.append(build_space(*a, **kw)) or spaces[-1]
    )
    sweep_file = tmp_path / "sweep.toml"
    sweep_file.write_text(f'dataset = "{folder.as_posix()}"\nexposure_ms = 5\nseeds = "0-1"\n')
    for flags, value in (([], "5"), (["--exposure-ms", "7"], "7")):
        args = ["sweep", str(sweep_file), *flags, "--dry-run", "--out", str(tmp_path / "s")]
        assert main(args) == 0
        assert spaces[-1].dataset.options == (("exposure_ms", value),) and len(spaces[-1].runs()) == 2


def test_open_dataset_takes_the_loaders_default_sequence(rendered: KittiOdometry):
    opened = open_dataset(rendered.root)  # no sequence: KITTI's default, "00"
    assert isinstance(opened, KittiOdometry) and opened.sequence == "00"
    np.testing.assert_array_equal(opened.frame_indices, rendered.frame_indices)
