"""Neural path integration of a real trajectory shape: the KITTI 00 ground truth (and a synthetic loop)."""

from __future__ import annotations

import hippo_nav
import numpy as np
import pytest
from hippo_nav.engine import SpatialMemory
from hippo_nav.engine.drive import drive, planar_odometry, planar_track
from hippo_nav.synthetic import loop_trajectory


def test_planar_odometry_recovers_a_loop():
    poses = loop_trajectory(120)
    t = 0.1 * np.arange(len(poses))
    odo = planar_odometry(poses, t)
    positions, yaw = planar_track(poses)
    # Speeds are chord lengths per second; turn rates integrate to the total heading change.
    assert np.all(odo.speed_m_s > 0)
    path_m = np.sum(np.linalg.norm(np.diff(positions, axis=0), axis=1))
    assert np.sum(odo.speed_m_s * odo.dt_s) == pytest.approx(path_m, rel=1e-12)
    assert abs(np.sum(odo.yaw_rate_rad_s * odo.dt_s) - np.unwrap(yaw)[-1]) < 1e-9
    with pytest.raises(hippo_nav.HippoNavError, match="increasing"):
        planar_odometry(poses, t[::-1])
    with pytest.raises(hippo_nav.HippoNavError, match="N >= 2"):
        planar_track(poses[:1])


@pytest.mark.slow
def test_network_integrates_the_kitti_00_ground_truth_shape(shared_data):
    from hippo_nav.io import read_kitti_poses

    poses = read_kitti_poses(shared_data / "kitti_odometry" / "poses" / "00.txt")[:600]
    times = np.loadtxt(shared_data / "kitti_odometry" / "sequences" / "00" / "times.txt")[:600]
    odo = planar_odometry(poses, times)
    result = drive(SpatialMemory(), odo)
    truth, _ = planar_track(poses)
    distance = np.sum(np.linalg.norm(np.diff(truth, axis=0), axis=1))
    err = np.linalg.norm(result.place_position_m - truth, axis=1)
    assert distance > 300
    # The network follows the real drive (turns included) to within 2 % of the distance travelled.
    assert err[-1] < 0.02 * distance, (err[-1], distance)
    assert (result.bump_counts[-1] == [1, 4, 16]).all()


def test_a_drive_with_arrays_of_different_lengths_and_absurd_seeds_are_refused():
    import dataclasses

    from hippo_nav import HippoNavError

    poses = loop_trajectory(20)
    odo = planar_odometry(poses, 0.1 * np.arange(len(poses)))
    short = dataclasses.replace(odo, dt_s=odo.dt_s[:-5])  # zip cut the drive to the shortest, without a word
    with pytest.raises(HippoNavError, match="differ in length"):
        drive(SpatialMemory(), short)
    sm = SpatialMemory()
    for heading, phase in ((1e17, (0.0, 0.0)), (0.0, (0.0, 1e20)), (0.0, (1.0,))):
        with pytest.raises(HippoNavError, match="reset angles|two angles"):
            sm.reset(heading, phase)
    sm.reset(2.0, (1.0, -1.0))
    assert sm.readout().heading_rad == pytest.approx(2.0, abs=0.05)


def test_a_network_state_without_a_part_is_refused_naming_it():
    from hippo_nav import HippoNavError

    sm = SpatialMemory()
    state = sm.state()
    del state["aux"]  # before: a bare KeyError
    with pytest.raises(HippoNavError, match="lacks aux"):
        sm.set_state(state)
