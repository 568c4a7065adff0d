"""`hippo-nav render`: a synthetic street along a KITTI ground truth, seen the same way on every pass,
written as a KITTI root that `hippo-nav run` reads, resumable."""

from __future__ import annotations

import numpy as np
import pytest
from hippo_nav.cli import main
from hippo_nav.datasets import DatasetError, KittiOdometry
from hippo_nav.io import read_kitti_poses, write_kitti_poses
from hippo_nav.synthetic import planar_poses, render_kitti, road_heights_m, road_trajectory

SIZE = (64, 24)


def out_and_back(heights_m: tuple[float, float]) -> np.ndarray:
    """40 m east at 2 m per frame, a U-turn, 40 m back on the same street: 42 frames. The two passes
    carry different ground-truth heights (as KITTI's do, by 0.3–3 m), plus a gentle slope."""
    x = np.concatenate([np.arange(0, 40, 2.0), [40.0, 40.0], np.arange(38, -2, -2.0)])
    yaw = np.concatenate([np.zeros(20), [np.pi / 2, np.pi], np.full(20, np.pi)])
    n = len(x)
    height = 0.02 * x + np.where(np.arange(n) < 21, heights_m[0], heights_m[1])
    return planar_poses(x, np.zeros(n), yaw, height_m=height)


def test_road_height_depends_on_the_place_only():
    poses = out_and_back((0.0, 2.0))
    heights = road_heights_m(poses[:, :3, 3])
    outbound, back = heights[:20], heights[22:][::-1]  # the same x positions, both passes
    np.testing.assert_allclose(outbound, back, atol=1e-9)
    # The passes disagreed by 2 m; the road lies between them and keeps its slope (0.02).
    assert 0.5 < heights[10] - 0.02 * 20 < 1.5
    assert np.polyfit(np.arange(0, 40, 2.0)[3:-3], outbound[3:-3], 1)[0] == pytest.approx(0.02, abs=0.005)
    level = road_trajectory(poses)
    np.testing.assert_allclose(level[:, 1, 3], -heights)
    np.testing.assert_allclose(level[:, [0, 2], 3], poses[:, [0, 2], 3])


@pytest.fixture()
def kitti_root(tmp_path):
    root = tmp_path / "kitti"
    poses = out_and_back((0.0, 1.5))
    write_kitti_poses(root / "poses" / "07.txt", poses)
    (root / "sequences" / "07").mkdir(parents=True)
    np.savetxt(root / "sequences" / "07" / "times.txt", 0.1 * np.arange(len(poses)) + 3.0)
    return root


def test_render_is_a_kitti_root_that_resumes(kitti_root, tmp_path):
    out = tmp_path / "render"
    render_kitti(kitti_root, "07", out, 0, 10, image_size_px=SIZE, workers=1)
    images = out / "sequences" / "07" / "image_0"
    first = {p.name: p.stat().st_mtime_ns for p in images.glob("*.png")}
    assert sorted(first) == [f"{i:06d}.png" for i in range(10)]
    # The partial render already reads as a KITTI sequence of the frames present.
    partial = KittiOdometry(out, "07")
    assert len(partial) == 10 and "10 of 42" in partial.note
    # A frame emptied or cut short since (a full disk, a copy that stopped) is rendered again on resuming.
    (images / "000003.png").write_bytes(b"")
    cut = out / "sequences" / "07" / "image_1" / "000007.png"
    cut.write_bytes(cut.read_bytes()[:-20])
    render_kitti(kitti_root, "07", out, image_size_px=SIZE, workers=1)
    assert len(list(images.glob("*.png"))) == 42
    assert all(
        (images / name).stat().st_mtime_ns == stamp
        for name, stamp in first.items()
        if name not in ("000003.png", "000007.png")
    )
    assert KittiOdometry(out, "07")[3].left.std() > 5 and KittiOdometry(out, "07")[7].right.std() > 5
    dataset = KittiOdometry(out, "07")
    np.testing.assert_allclose(dataset.timestamps_s, 0.1 * np.arange(42) + 3.0)
    truth = read_kitti_poses(out / "poses" / "07.txt")
    np.testing.assert_allclose(truth, road_trajectory(read_kitti_poses(kitti_root / "poses" / "07.txt")))
    frame = dataset[5]
    assert frame.left.shape == (SIZE[1], SIZE[0]) and frame.left.std() > 5
    with pytest.raises(DatasetError, match="other settings"):
        render_kitti(kitti_root, "07", out, image_size_px=(96, 32), workers=1)


def test_render_command_and_its_errors(kitti_root, tmp_path, capsys):
    out = tmp_path / "cli"
    args = ["render", "--kitti", str(kitti_root), "--sequence", "07", "--out", str(out), "--no-progress"]
    assert main([*args, "--size", "64x24", "--stop", "3"]) == 0
    assert "hippo-nav run --dataset" in capsys.readouterr().out
    assert len(list((out / "sequences" / "07" / "image_1").glob("*.png"))) == 3
    assert main([*args, "--size", "64by24"]) == 2
    assert "--size" in capsys.readouterr().err
    assert main([*args[:4], "08", *args[5:]]) == 2
    err = capsys.readouterr().err
    assert "08.txt" in err and len(err.strip().splitlines()) == 1


def test_render_never_writes_outside_out_nor_over_a_sequence_it_did_not_write(kitti_root, tmp_path, capsys):
    """`--out` equal to the KITTI root read, an `--out` holding someone else's sequence, a sequence that is a
    path, an absurd size: each is one line, exit 2, and no file anywhere is written or changed."""
    poses = (kitti_root / "poses" / "07.txt").read_bytes()
    before = sorted(p for p in tmp_path.rglob("*"))
    base = ["render", "--kitti", str(kitti_root), "--no-progress", "--size", "64x24", "--stop", "2"]

    def refused(*extra: str, match: str) -> None:
        assert main([*base, *extra]) == 2
        err = capsys.readouterr().err
        assert match in err and len(err.strip().splitlines()) == 1, err
        assert sorted(p for p in tmp_path.rglob("*")) == before
        assert (kitti_root / "poses" / "07.txt").read_bytes() == poses

    refused("--sequence", "07", "--out", str(kitti_root), match="is the KITTI root being read")
    refused(
        "--sequence", "07", "--out", str(kitti_root / "." / "sequences" / ".."), match="KITTI root being read"
    )
    refused("--sequence", "../../escape", "--out", str(tmp_path / "out"), match="must be a name")
    refused("--sequence", "..", "--out", str(tmp_path / "out"), match="must be a name")
    # A KITTI copy of the user's own (poses and times of 07, no render stamp) is not overwritten.
    theirs = tmp_path / "theirs"
    (theirs / "poses").mkdir(parents=True)
    (theirs / "poses" / "07.txt").write_bytes(poses)
    before = sorted(p for p in tmp_path.rglob("*"))
    refused("--sequence", "07", "--out", str(theirs), match="did not write")
    assert (theirs / "poses" / "07.txt").read_bytes() == poses
    # An absurd size is refused before anything is written, so the corrected command then runs.
    out = tmp_path / "out"
    refused("--sequence", "07", "--out", str(out), "--size", "100000x100000", match="16 to 4096 px")
    args = [*base, "--sequence", "07", "--out", str(out)]
    assert main(args) == 0
    assert len(list((out / "sequences" / "07" / "image_0").glob("*.png"))) == 2
