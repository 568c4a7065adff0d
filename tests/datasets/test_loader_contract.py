"""The loader contract (`StereoLoader`): every registered loader follows it, the command line derives its
choices from the registry, and any dataset's optional attributes are read in one place with defaults."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest
from hippo_nav.cli import build_parser, main
from hippo_nav.datasets import LOADERS, DatasetExtras, KittiOdometry, StereoLoader, open_dataset


def _run_options(parser: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {flag: action for action in sub.choices["run"]._actions for flag in action.option_strings}


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


def test_open_dataset_takes_the_loaders_default_sequence(rendered: KittiOdometry):
    opened = open_dataset(rendered.root)  # no sequence: KITTI's default, "00"
    assert isinstance(opened, KittiOdometry) and opened.sequence == "00"
    np.testing.assert_array_equal(opened.frame_indices, rendered.frame_indices)
