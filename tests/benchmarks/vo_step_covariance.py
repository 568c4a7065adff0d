"""Does the VO's own uncertainty say where its heading goes wrong? (docs/results.md, "Where 02's error comes from")

    python tests/benchmarks/vo_step_covariance.py --dataset ROOT --sequence NN [--start A] [--stop B] [--bin 50]

Runs the built-in VO over the frames and, for every step, the covariance of the step's stereo refinement
(`hippo_nav.vo.projection.refine_stereo_step`: the left and right reprojections of the previous frame's points in
this frame) with the points' own stereo uncertainty marginalised: each point is triangulated from pixels of
`--pixel-sigma` and a disparity of `--disparity-sigma`, and that uncertainty, carried into this frame, widens its
residuals. A pose graph whose odometry links carried this covariance would put a loop's correction where it is
large. Printed per bin of frames, against the ground truth: the heading the VO gained (`vo_step_errors.step_errors`),
the predicted deviation of that gain (√Σσ² of the steps' yaw) and the predicted correlation of a step's yaw and
sideways motion. Not a test (no assertions; pytest does not collect it).
"""

from __future__ import annotations

import argparse

import numpy as np
from hippo_nav.datasets import open_dataset
from hippo_nav.vo import odometry
from hippo_nav.vo.projection import pixel_rows
from vo_step_errors import step_errors  # the sibling script (Python puts a script's folder on sys.path)

YAW, SIDEWAYS = 1, 3  # in the step's perturbation (ω, τ): the rotation about the camera's y axis, the x shift


def step_covariance(
    cur_from_prev: np.ndarray,
    points_m: np.ndarray,
    has_right: np.ndarray,
    camera: tuple[float, float, float, float, float],
    pixel_sigma: float,
    disparity_sigma: float,
) -> np.ndarray | None:
    """6 × 6 covariance of the step (a left perturbation (ω, τ)), the points' stereo uncertainty marginalised."""
    fx, fy, cx, cy, baseline_m = camera
    rotation = cur_from_prev[:3, :3]
    x = points_m @ rotation.T + cur_from_prev[:3, 3]
    depth = points_m[:, 2]
    u, v = fx * points_m[:, 0] / depth + cx, fy * points_m[:, 1] / depth + cy
    disparity = fx * baseline_m / depth
    # The point's covariance from its triangulation (u, v, d) in the previous camera.
    tri = np.zeros((len(points_m), 3, 3))
    d_depth = -depth / disparity
    tri[:, 0, 0], tri[:, 1, 1] = depth / fx, depth / fy
    tri[:, 0, 2], tri[:, 1, 2], tri[:, 2, 2] = (u - cx) / fx * d_depth, (v - cy) / fy * d_depth, d_depth
    point_cov = tri @ np.diag([pixel_sigma**2, pixel_sigma**2, disparity_sigma**2]) @ tri.transpose(0, 2, 1)
    rows = []
    for axis, shift in ((0, 0.0), (1, 0.0), (0, baseline_m)):  # left u, left v, right u
        _, jac, d_a, d_z = pixel_rows(x, axis, shift, camera[:4])
        on_point = np.zeros((len(x), 3))
        on_point[:, axis], on_point[:, 2] = d_a, d_z
        rows.append((jac, on_point @ rotation))
    information = np.zeros((6, 6))
    for i in range(len(x)):
        n = 3 if has_right[i] else 2
        on_pose = np.stack([rows[r][0][i] for r in range(n)])
        on_point_i = np.stack([rows[r][1][i] for r in range(n)])
        residual_cov = pixel_sigma**2 * np.eye(n) + on_point_i @ point_cov[i] @ on_point_i.T
        information += on_pose.T @ np.linalg.solve(residual_cov, on_pose)
    try:
        return np.linalg.inv(information)
    except np.linalg.LinAlgError:
        return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", required=True)
    parser.add_argument("--sequence", required=True)
    parser.add_argument("--start", type=int, default=0)
    parser.add_argument("--stop", type=int, default=None)
    parser.add_argument("--bin", type=int, default=50)
    parser.add_argument("--pixel-sigma", type=float, default=0.5)
    parser.add_argument("--disparity-sigma", type=float, default=0.5)
    args = parser.parse_args()

    dataset = open_dataset(args.dataset, sequence=args.sequence, start=args.start, stop=args.stop)
    covariances: dict[int, np.ndarray | None] = {}
    frame = [0]
    refine = odometry.refine_stereo_step

    def measured(cur_from_prev, points_m, left_px, right_px, has_right, camera, huber_px, offset_px):
        step = refine(cur_from_prev, points_m, left_px, right_px, has_right, camera, huber_px, offset_px)
        covariances[frame[0]] = step_covariance(
            step, points_m, has_right, camera, args.pixel_sigma, args.disparity_sigma
        )
        return step

    odometry.refine_stereo_step = measured  # the odometry calls it by this module's name
    vo = odometry.StereoOdometry(dataset.calibration)
    poses, world_from_camera = [], np.eye(4)
    for i in range(len(dataset)):
        frame[0] = i
        world_from_camera = world_from_camera @ vo.process(dataset[i]).camera_prev_from_camera_cur
        poses.append(world_from_camera)
    truth = dataset.ground_truth()
    if truth is None:
        raise SystemExit(f"{args.dataset} {args.sequence}: no ground truth to compare with")
    errors = step_errors(np.asarray(truth), np.stack(poses))
    steps = len(errors["yaw_deg"])
    sigma_yaw_deg, correlation = np.full(steps, np.nan), np.full(steps, np.nan)
    for i in range(steps):
        cov = covariances.get(i + 1)
        if cov is not None:
            sigma_yaw_deg[i] = np.degrees(np.sqrt(cov[YAW, YAW]))
            correlation[i] = cov[YAW, SIDEWAYS] / np.sqrt(cov[YAW, YAW] * cov[SIDEWAYS, SIDEWAYS])
    first = dataset.frame_indices[0]
    print(f"{'frames':>11}  {'heading gained':>14}  {'predicted sd':>12}  {'corr(yaw, x) predicted':>22}")
    gains, deviations = [], []
    for a in range(0, steps - args.bin + 1, args.bin):
        bin_ = slice(a, a + args.bin)
        gains.append(np.nansum(errors["yaw_deg"][bin_]))
        deviations.append(np.sqrt(np.nansum(sigma_yaw_deg[bin_] ** 2)))
        print(
            f"{first + a:5d}-{first + a + args.bin - 1:5d}  {gains[-1]:+13.3f}°  {deviations[-1]:11.3f}°  "
            f"{np.nanmean(correlation[bin_]):+22.2f}"
        )
    gains_a, deviations_a = np.abs(np.array(gains)), np.array(deviations)
    print(f"bins: corr(|heading gained|, predicted sd) {np.corrcoef(gains_a, deviations_a)[0, 1]:+.2f}")
    measured_steps = np.isfinite(sigma_yaw_deg)
    print(
        "steps: mean |yaw error| "
        f"{np.mean(np.abs(errors['yaw_deg'][measured_steps])):.4f}°, mean predicted sd "
        f"{np.mean(sigma_yaw_deg[measured_steps]):.4f}°, corr "
        f"{np.corrcoef(np.abs(errors['yaw_deg'][measured_steps]), sigma_yaw_deg[measured_steps])[0, 1]:+.2f}"
    )


if __name__ == "__main__":
    main()
