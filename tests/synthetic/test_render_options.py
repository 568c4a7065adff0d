"""`hippo-nav render` (--appearance, --poles, the integers and the size) and `hippo-nav figures` given bad
values: one clear line and exit 2, before anything is written; the library functions behind them refuse the
same values with a `HippoNavError` naming the option (a negative seed was a NumPy traceback)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hippo_nav._core import HippoNavError
from hippo_nav.cli import main
from hippo_nav.synthetic import render_kitti
from hippo_nav.synthetic.figures import appearance_figure, appearance_images


@pytest.fixture
def kitti(tmp_path) -> Path:
    """A KITTI root of 6 ground-truth poses (1 m apart, straight ahead) and their times: nothing else is read."""
    root = tmp_path / "kitti"
    (root / "poses").mkdir(parents=True)
    (root / "sequences" / "00").mkdir(parents=True)
    lines = []
    for i in range(6):
        pose = np.eye(4)
        pose[2, 3] = float(i)
        lines.append(" ".join(f"{v:.6f}" for v in pose[:3].ravel()))
    (root / "poses" / "00.txt").write_text("\n".join(lines) + "\n", encoding="utf-8")
    (root / "sequences" / "00" / "times.txt").write_text(
        "\n".join(f"{0.1 * i:.6f}" for i in range(6)) + "\n", encoding="utf-8"
    )
    return root


def _exit_code(argv: list[str]) -> int:
    """`main`'s code (argparse's 2 on a value its `choices`/`type=` refuse included)."""
    return main(argv)


def _error_line(capsys: pytest.CaptureFixture[str]) -> str:
    """The one error line; never a usage dump, a traceback or `[Errno …]`."""
    err = capsys.readouterr().err
    assert "Traceback" not in err and "[Errno" not in err, err
    errors = err.strip().splitlines()
    assert len(errors) == 1 and "error:" in errors[0], err
    return errors[0]


@pytest.mark.parametrize(
    ("option", "named"),
    [
        (["--appearance", "nope"], "--appearance"),
        (["--appearance", ""], "--appearance"),
        (["--poles=yes"], "--poles"),
        (["--seed", "-1"], "--seed"),
        (["--seed", "9" * 40], "--seed"),
        (["--workers", "0"], "--workers"),
        (["--workers", "-3"], "--workers"),
        (["--workers", "10000000"], "--workers"),
        (["--size", "0x0"], "--size"),
        (["--size", "100000x100000"], "--size"),
        (["--size=-5x3"], "--size"),
        (["--size", "320x96x3"], "--size"),
    ],
)
def test_a_bad_render_option_is_one_line_exit_2_and_nothing_written(kitti, tmp_path, capsys, option, named):
    out = tmp_path / "out"
    argv = ["render", "--kitti", str(kitti), "--sequence", "00", "--out", str(out), "--no-progress", *option]
    assert _exit_code(argv) == 2
    assert named in _error_line(capsys)
    assert not out.exists()


def test_render_out_under_a_file_is_one_line(kitti, tmp_path, capsys):
    a_file = tmp_path / "a_file"
    a_file.write_text("x", encoding="utf-8")
    argv = ["render", "--kitti", str(kitti), "--sequence", "00", "--out", str(a_file / "x"), "--no-progress"]
    assert _exit_code(argv) == 2
    assert "Not a directory" in _error_line(capsys)


@pytest.mark.parametrize(
    ("keywords", "named"),
    [
        ({"seed": -1}, "seed"),
        ({"seed": 2**64}, "seed"),
        ({"seed": 1.5}, "seed"),
        ({"workers": -3}, "workers"),
        ({"workers": 10**6}, "workers"),
        ({"poles": "yes"}, "poles"),
        ({"appearance": "nope"}, "appearance"),
        ({"appearance": None}, "appearance"),
        ({"image_size_px": (0, 10)}, "image size"),
    ],
)
def test_render_kitti_refuses_bad_options_before_writing(kitti, tmp_path, keywords, named):
    out = tmp_path / "out"
    with pytest.raises(HippoNavError, match=named):
        render_kitti(kitti, "00", out, **keywords)
    assert not out.exists()


def test_a_bad_figures_out_is_one_line_exit_2(tmp_path, capsys):
    a_file = tmp_path / "a_file"
    a_file.write_text("x", encoding="utf-8")
    for extra in ([], ["--appearance"]):
        assert _exit_code(["figures", "--out", str(a_file), *extra]) == 2
        assert "not a folder" in _error_line(capsys)
        assert _exit_code(["figures", "--out", str(a_file / "below"), *extra]) == 2
        assert "cannot create the folder" in _error_line(capsys)
    assert _exit_code(["figures", "--appearance=yes", "--out", str(tmp_path)]) == 2
    assert "--appearance" in _error_line(capsys)
    assert a_file.read_text(encoding="utf-8") == "x"


@pytest.mark.parametrize(
    "keywords",
    [
        {"image_size_px": (0, 0)},
        {"image_size_px": (10**6, 96)},
        {"seed": -1},
        {"frame": 10**9},
        {"frame": -1},
    ],
)
def test_the_appearance_figure_refuses_absurd_sizes_seeds_and_frames(tmp_path, keywords):
    with pytest.raises(HippoNavError):
        appearance_images(**keywords)
    if "frame" not in keywords:
        with pytest.raises(HippoNavError):
            appearance_figure(tmp_path / "a.png", **keywords)
    assert not (tmp_path / "a.png").exists()
