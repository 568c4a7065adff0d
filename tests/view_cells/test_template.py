"""The template view descriptor through the Python package: templates, matching, headings, bad input, real images."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from hippo_nav import HippoNavError, _core
from hippo_nav.datasets import KittiOdometry
from hippo_nav.synthetic import DEMO_SEQUENCE, demo_sequence
from hippo_nav.view_cells import TemplateViewCells, TemplateViewConfig, field_of_view_rad
from pydantic import ValidationError


def textured_image(seed: int, shape: tuple[int, int] = (376, 1241)) -> np.ndarray:
    """Smooth random texture in 0–255 (blurred noise, like a street scene's mid frequencies)."""
    rng = np.random.default_rng(seed)
    noise = rng.normal(size=shape).astype(np.float32)
    smooth = cv2.GaussianBlur(noise, (0, 0), 6)
    smooth = (smooth - smooth.min()) / np.ptp(smooth) * 255
    return smooth.astype(np.uint8)


def test_python_defaults_are_the_rust_defaults() -> None:
    rust = json.loads(_core.default_params_json("views"))
    python = json.loads(TemplateViewConfig().model_dump_json())
    assert python == rust
    assert json.loads(_core._ViewCells(TemplateViewConfig().model_dump_json()).params_json()) == rust


def test_template_is_patch_normalised_and_exposure_invariant() -> None:
    cells = TemplateViewCells()
    img = textured_image(0)
    t = cells.template_from_image(img)
    cfg = cells.config
    assert t.shape == (cfg.height_px, cfg.width_px) and t.dtype == np.float32
    assert abs(float(t.mean())) < 0.2 and 0.5 < float(np.abs(t).mean()) < 1.5
    darker = (img.astype(np.float32) * 0.6 + 30).astype(np.uint8)
    cells.observe(t)
    obs = cells.observe(cells.template_from_image(darker))
    assert obs.status == "familiar" and obs.cell_id == 0 and obs.shift_px == 0
    assert obs.difference < 0.1


def test_any_layout_gives_the_same_answer() -> None:
    cells = TemplateViewCells()
    img = textured_image(1)
    t = cells.template_from_image(img)
    assert np.array_equal(cells.template_from_image(np.asfortranarray(img)), t)
    wide = np.zeros((img.shape[0], 2 * img.shape[1]), np.uint8)
    wide[:, ::2] = img
    assert np.array_equal(cells.template_from_image(wide[:, ::2]), t)
    cells.add(t)
    strided = np.zeros((t.shape[0], 2 * t.shape[1]), np.float64)
    strided[:, ::2] = t
    assert cells.best_match(strided[:, ::2]) == cells.best_match(t)
    assert cells.best_match(np.ascontiguousarray(t.T).T) == cells.best_match(t)


def test_turning_left_gives_a_positive_relative_heading() -> None:
    fov = field_of_view_rad(718.856, 1241)
    cells = TemplateViewCells(TemplateViewConfig(field_of_view_rad=fov))
    img = textured_image(2, (376, 1400))
    for seed in range(3, 8):  # other places, so the match has competition
        cells.observe(cells.template_from_image(textured_image(seed)[:, :1241]))
    stored = cells.observe(cells.template_from_image(img[:, 80:1321]))
    assert stored.is_new
    # The camera turned left: the scene slides right by 4 template columns (about 78 image px).
    cols_per_template_px = 1241 / cells.config.width_px
    slid = round(4 * cols_per_template_px)
    obs = cells.observe(cells.template_from_image(img[:, 80 - slid : 1321 - slid]))
    assert (obs.status, obs.cell_id) == ("familiar", stored.cell_id)
    assert obs.shift_px == 4
    assert obs.relative_heading_rad == pytest.approx(4 * fov / cells.config.width_px)
    assert len(cells) == 6


def test_unrelated_places_become_new_cells_and_blank_frames_are_uninformative() -> None:
    cells = TemplateViewCells()
    results = [cells.observe(cells.template_from_image(textured_image(s))) for s in range(10, 20)]
    assert all(r.is_new for r in results) and [r.cell_id for r in results] == list(range(10))
    assert all(0.5 < r.difference <= 1.0 for r in results)
    blank = cells.observe(cells.template_from_image(np.full((376, 1241), 90, np.uint8)))
    assert (blank.status, blank.cell_id, blank.is_new) == ("uninformative", None, False)
    assert len(cells) == 10
    assert cells.templates().shape == (10, cells.config.height_px, cells.config.width_px)


def test_any_layout_and_dtype_give_the_same_template() -> None:
    cells = TemplateViewCells()
    img = textured_image(3)
    t = cells.template_from_image(img)
    assert np.array_equal(cells.template_from_image(img[:, ::1]), t)
    assert np.array_equal(cells.template_from_image(np.ascontiguousarray(img.T).T), t)
    assert np.array_equal(cells.template_from_image(img[::-1][::-1]), t)
    for dtype in (np.float32, np.float64, np.uint16, np.int32):
        assert np.array_equal(cells.template_from_image(img.astype(dtype)), t), dtype
    # A float image in Fortran order with a column stride.
    wide = np.zeros((img.shape[0], 3 * img.shape[1]), np.float64, order="F")
    wide[:, 1::3] = img
    assert np.array_equal(cells.template_from_image(wide[:, 1::3]), t)
    # Templates of any layout or float width are matched the same way.
    cells.add(t)
    cells.add(cells.template_from_image(textured_image(4)))
    want = cells.best_match(t)
    assert cells.best_match(t.astype(np.float64)) == want
    assert cells.best_match(np.asfortranarray(t)) == want
    assert cells.observe(t[::-1][::-1]).cell_id == 0


def test_pruned_search_equals_brute_force() -> None:
    """The fast `best_match` is exact: same cell, difference and shift as the exhaustive search."""
    rng = np.random.default_rng(7)
    cells = TemplateViewCells()
    base = [cells.template_from_image(textured_image(100 + k, (120, 400))) for k in range(40)]
    for t in base:
        cells.add(t)
    cells.add(base[5])  # an exact duplicate: ties go to the lowest id
    core = cells._cells
    queries = [
        b + rng.normal(scale=s, size=b.shape).astype(np.float32) for b, s in zip(base, [0.1, 0.5, 1.0] * 14)
    ]
    queries += [
        np.roll(base[9], 3, axis=1),
        base[5],
        cells.template_from_image(textured_image(999, (120, 400))),
    ]
    for q in queries:
        fast, brute = cells.best_match(q), core.best_match_brute_force(q)
        assert fast is not None and brute is not None
        assert (fast[0], fast[2]) == (brute[0], brute[2])
        assert fast[1] == pytest.approx(brute[1], abs=1e-6)
        d, s = cells.differences(q)
        assert d.shape == s.shape == (len(cells),) and d.dtype == np.float32 and s.dtype == np.int32
        assert fast[0] == int(np.argmin(d)) and fast[1] == pytest.approx(float(d.min()), abs=1e-6)
        assert s[fast[0]] == fast[2]
    assert cells.best_match(base[5])[:2] == (5, 0.0)
    assert cells.best_match(np.roll(base[9], 3, axis=1))[0] == 9
    assert TemplateViewCells().best_match(base[0]) is None


def test_restricted_search_is_exact_within_the_candidates() -> None:
    """`candidates` restricts the search: the answer is brute force over those cells (via `differences`)."""
    rng = np.random.default_rng(11)
    cells = TemplateViewCells()
    base = [cells.template_from_image(textured_image(200 + k, (120, 400))) for k in range(60)]
    for t in base:
        cells.add(t)
    d_all = {}
    for k in range(12):
        q = base[(7 * k) % 60] + rng.normal(scale=0.4, size=base[0].shape).astype(np.float32)
        d_all[k] = cells.differences(q)[0]
        subset = rng.choice(60, size=1 + (5 * k) % 25, replace=False)
        ids = np.r_[subset, subset[: len(subset) // 2]]  # duplicates are fine
        got = cells.best_match(q, ids)
        assert got is not None
        want = int(subset[np.argmin(d_all[k][subset])])
        if d_all[k][subset].tolist().count(d_all[k][want]) == 1:
            assert got[0] == want
        assert got[1] == pytest.approx(float(d_all[k][subset].min()), abs=1e-6)
        # Any integer sequence or array layout gives the same answer.
        assert cells.best_match(q, ids.tolist()) == got
        assert cells.best_match(q, ids.astype(np.int32)[::-1]) == got
        assert cells.best_match(q, np.repeat(ids, 2)[::2].astype(np.uint64)) == got
    q = base[9]
    assert cells.best_match(q, None) == cells.best_match(q) == (9, 0.0, 0)
    assert cells.best_match(q, []) is None
    assert cells.best_match(q, np.arange(60)) == cells.best_match(q)


def test_restricted_observe_is_familiar_only_among_the_candidates() -> None:
    cells = TemplateViewCells()
    for seed in range(300, 310):
        cells.observe(cells.template_from_image(textured_image(seed, (120, 400))))
    revisit = cells.template_from_image(textured_image(304, (120, 400)))
    obs = cells.observe(revisit, candidates=[1, 4, 4, 8])
    assert (obs.status, obs.cell_id) == ("familiar", 4)
    assert len(cells) == 10
    # Without its own cell among the candidates the view is novel there: a new cell is made for it.
    obs = cells.observe(revisit, candidates=np.array([0, 1, 2]))
    assert (obs.status, obs.cell_id) == ("new", 10) and obs.difference > cells.config.novelty_threshold
    obs = cells.observe(revisit, candidates=[])
    assert (obs.status, obs.cell_id, obs.difference) == ("new", 11, 1.0)
    blank = cells.observe(np.zeros((24, 64), np.float32), candidates=[0])
    assert blank.status == "uninformative" and len(cells) == 12


def test_bad_candidates_raise_clear_errors_and_store_nothing() -> None:
    cells = TemplateViewCells()
    t = cells.template_from_image(textured_image(400, (120, 400)))
    cells.add(t)
    other = cells.template_from_image(textured_image(401, (120, 400)))
    with pytest.raises(HippoNavError, match="candidate 1 is view cell 5, which does not exist"):
        cells.observe(other, candidates=[0, 5])
    with pytest.raises(HippoNavError, match="candidate 2 is -1: view-cell ids are ≥ 0"):
        cells.best_match(other, np.array([0, 0, -1]))
    with pytest.raises(HippoNavError, match="must be integers"):
        cells.best_match(other, [0.0, 1.5])
    with pytest.raises(HippoNavError, match="1-D"):
        cells.observe(other, candidates=np.zeros((2, 2), np.int64))
    with pytest.raises(HippoNavError, match="does not exist"):
        cells.observe(other, candidates=np.array([2**64 - 1], np.uint64))
    assert len(cells) == 1


def test_templates_round_trip_through_add() -> None:
    cells = TemplateViewCells()
    for seed in range(30, 36):
        cells.observe(cells.template_from_image(textured_image(seed, (120, 400))))
    saved = cells.templates()
    assert saved.shape == (6, 24, 64) and saved.dtype == np.float32
    restored = TemplateViewCells(cells.config)
    assert [restored.add(t) for t in saved] == list(range(6))
    assert np.array_equal(restored.templates(), saved)
    q = cells.template_from_image(textured_image(33, (120, 400)))
    assert restored.best_match(q) == cells.best_match(q) == (3, 0.0, 0)


def test_bad_input_raises_clear_errors() -> None:
    cells = TemplateViewCells()
    with pytest.raises(HippoNavError, match=r"gray image of shape \(H, W\).*cvtColor"):
        cells.template_from_image(np.zeros((376, 1241, 3), np.uint8))
    with pytest.raises(HippoNavError, match=r"gray image of shape \(H, W\), got shape \(1241,\)"):
        cells.template_from_image(np.zeros(1241, np.uint8))
    with pytest.raises(HippoNavError, match="too small for a 24×64 template"):
        cells.template_from_image(np.zeros((10, 10), np.uint8))
    with pytest.raises(HippoNavError, match="too small"):
        cells.template_from_image(np.zeros((376, 40), np.uint8))  # tall enough, too narrow
    with pytest.raises(HippoNavError, match="too small"):
        cells.template_from_image(np.zeros((39, 1241), np.uint8))  # 0.6 × 39 rows < 24 after cropping
    with pytest.raises(HippoNavError, match="not numeric"):
        cells.template_from_image(np.full((376, 1241), "a"))
    nan_image = textured_image(0).astype(np.float32)
    nan_image[200, 5] = np.nan
    with pytest.raises(HippoNavError, match="NaN"):
        cells.template_from_image(nan_image)
    inf_image = textured_image(0).astype(np.float64)
    inf_image[100, 5] = -np.inf
    with pytest.raises(HippoNavError, match="infinite"):
        cells.template_from_image(inf_image)
    # Templates: wrong shape (including transposed and flat), non-finite values, non-numeric.
    for bad_shape in [(64, 24), (24 * 64,), (1, 24, 64), (24, 63)]:
        with pytest.raises(HippoNavError, match=r"expected \(24, 64\) = \(height_px, width_px\)"):
            cells.observe(np.zeros(bad_shape, np.float32))
        with pytest.raises(HippoNavError, match=r"expected \(24, 64\)"):
            cells.best_match(np.zeros(bad_shape, np.float64))
        with pytest.raises(HippoNavError, match=r"expected \(24, 64\)"):
            cells.add(np.zeros(bad_shape, np.float32))
    t = np.zeros((24, 64), np.float32)
    t[3, 7] = np.inf
    with pytest.raises(HippoNavError, match="row 3, column 7 is not finite"):
        cells.observe(t)
    t[3, 7] = np.nan
    with pytest.raises(HippoNavError, match="not finite"):
        cells.add(t)
    with pytest.raises(HippoNavError, match="not numeric"):
        cells.observe(np.full((24, 64), "x"))
    assert len(cells) == 0  # nothing was stored by the failed calls
    # Configuration: every check names the parameter and says what is allowed.
    bad_configs = [
        ({"crop_rows_frac": (0.7, 0.1)}, r"crop_rows_frac.*0 ≤ top < bottom ≤ 1"),
        ({"crop_rows_frac": (0.1, 1.5)}, "crop_rows_frac"),
        ({"novelty_threshold": -0.1}, r"novelty_threshold.*inside \(0, 1\)"),
        ({"novelty_threshold": 1.5}, "novelty_threshold"),
        ({"min_texture": -1.0}, r"min_texture.*≥ 0"),
        ({"patch_size_px": 4}, "patch_size_px.*odd"),
        ({"max_shift_px": 40}, "max_shift_px.*half the template width"),
        ({"width_px": 2, "max_shift_px": 0}, "width_px"),
        ({"height_px": 0}, "height_px"),
        ({"field_of_view_rad": 0.0}, r"field_of_view_rad.*\(0, 2π\)"),
        ({"coarse_rows": 0}, "coarse_rows"),
    ]
    for fields, message in bad_configs:
        # Refused by the config model, naming the field; and by the Rust cells, for a config made unchecked.
        with pytest.raises(ValidationError, match=message.split(".*")[0]):
            TemplateViewConfig(**fields)
        with pytest.raises(HippoNavError, match=message):
            TemplateViewCells(TemplateViewConfig.model_construct(**fields))
    with pytest.raises(ValidationError):
        TemplateViewConfig(width=64)  # type: ignore[call-arg]
    with pytest.raises(HippoNavError, match="invalid view-cell config"):
        _core._ViewCells('{"width_px": "wide"}')
    with pytest.raises(HippoNavError, match="fx_px > 0"):
        field_of_view_rad(0.0, 1241)
    with pytest.raises(HippoNavError, match="image_width_px > 0"):
        field_of_view_rad(700.0, 0)


def test_blank_and_dark_frames_are_uninformative() -> None:
    cells = TemplateViewCells()
    cells.observe(cells.template_from_image(textured_image(50)))
    for value in (0, 90, 255):
        blank = np.full((376, 1241), value, np.uint8)
        t = cells.template_from_image(blank)
        assert float(np.abs(t).max()) < 1e-3  # box-filter rounding leaves only tiny residues
        obs = cells.observe(t)
        assert (obs.status, obs.cell_id, obs.is_new, obs.difference, obs.shift_px) == (
            "uninformative",
            None,
            False,
            1.0,
            0,
        )
        assert obs.relative_heading_rad == 0.0
    # A gentle exposure ramp (vignetting, a blank wall) is removed by patch normalisation.
    ramp = np.broadcast_to(np.linspace(60, 120, 1241), (376, 1241))
    assert cells.observe(cells.template_from_image(ramp)).status == "uninformative"
    assert len(cells) == 1
    # A dark frame of pure sensor noise (σ = 1 and 2 grey levels) is not a place: no cell is made for it,
    # while the same textured scene at 1/12 of its brightness still is informative.
    rng = np.random.default_rng(3)
    for shape in ((376, 1241), (96, 320)):
        for sigma in (1.0, 2.0):
            noise = np.clip(20 + rng.normal(0, sigma, shape), 0, 255).astype(np.uint8)
            assert cells.observe(cells.template_from_image(noise)).status == "uninformative", (shape, sigma)
    assert len(cells) == 1
    dim = (textured_image(52) // 12).astype(np.uint8)
    assert cells.observe(cells.template_from_image(dim)).status == "new"
    # A float image scaled to [0, 1] is a units mistake, not a blank view.
    with pytest.raises(HippoNavError, match="multiply by 255"):
        cells.template_from_image(textured_image(53) / 255.0)
    # The empty store: a textured view becomes cell 0 with difference 1.
    fresh = TemplateViewCells()
    obs = fresh.observe(fresh.template_from_image(textured_image(51)))
    assert (obs.status, obs.cell_id, obs.difference) == ("new", 0, 1.0)


def _ccw_heading_rad(world_from_camera: np.ndarray) -> np.ndarray:
    """Heading (counter-clockwise seen from above) of cameras with x right, y down, z forward."""
    forward = world_from_camera[:, :3, 2]
    return np.arctan2(-forward[:, 0], forward[:, 2])


def _wrap(a: np.ndarray | float) -> np.ndarray:
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


@pytest.mark.slow  # renders the demo once (tens of seconds) when it is not cached yet
def test_second_lap_of_the_synthetic_loop_recognises_the_first() -> None:
    dataset = KittiOdometry(demo_sequence(), DEMO_SEQUENCE)
    poses = dataset.ground_truth()
    assert poses is not None
    calib = dataset.calibration
    fov = field_of_view_rad(calib.fx, calib.image_size_px[0])
    cells = TemplateViewCells(TemplateViewConfig(field_of_view_rad=fov))
    position = poses[:, :3, 3][:, [0, 2]]  # ground plane (x, z)
    heading = _ccw_heading_rad(poses)
    travelled = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1))]
    near_m, near_rad, loop_gap_m = 5.0, np.radians(30), 30.0

    created_at: dict[int, int] = {}
    observations = []
    for i in range(len(dataset)):
        obs = cells.observe(cells.template_from_image(dataset[i].left))
        if obs.is_new:
            created_at[obs.cell_id] = i
        observations.append(obs)

    def close(i: int, j: np.ndarray | int) -> np.ndarray:
        return (np.linalg.norm(position[j] - position[i], axis=-1) <= near_m) & (
            np.abs(_wrap(heading[j] - heading[i])) <= near_rad
        )

    # True revisits: frames close to a frame driven at least `loop_gap_m` earlier (the second lap).
    revisit = np.array(
        [
            bool((close(i, np.arange(i)) & (travelled[i] - travelled[:i] > loop_gap_m)).any())
            for i in range(len(poses))
        ]
    )
    loop_claims = correct = familiar = familiar_close = 0
    heading_errors = []
    for i, obs in enumerate(observations):
        if obs.status != "familiar":
            continue
        j = created_at[obs.cell_id]
        # Every familiar view, temporal neighbour or loop closure, should come from a nearby pose.
        familiar += 1
        familiar_close += bool(close(i, j))
        if travelled[i] - travelled[j] > loop_gap_m:
            loop_claims += 1
            correct += bool(close(i, j))
            # The measured relative heading agrees with the ground truth to about one template column.
            truth = float(_wrap(heading[i] - heading[j]))
            heading_errors.append(obs.relative_heading_rad - truth)
            if close(i, j) and abs(truth) > np.radians(2.5):
                assert np.sign(obs.relative_heading_rad) == np.sign(truth), (i, j, obs, truth)
    precision = correct / loop_claims
    recall = correct / revisit.sum()
    # Measured: 124 cells for 200 frames, 76 familiar views, 63 loop claims all correct (precision 1.0),
    # 71 true revisit frames (129–199) so recall 0.89; heading errors ≤ 1.2° (one column is 1.3°).
    assert revisit.sum() >= 60
    assert familiar_close >= 0.95 * familiar, (familiar_close, familiar)
    assert precision >= 0.95, (correct, loop_claims)
    assert recall >= 0.75, (correct, int(revisit.sum()))
    assert np.abs(heading_errors).max() <= 2 * fov / cells.config.width_px
    assert len(cells) < 0.8 * len(dataset)  # the second lap mostly reuses first-lap cells


@pytest.mark.data
def test_kitti_consecutive_frames_are_familiar_and_distant_ones_are_not(shared_data) -> None:
    seq = shared_data / "kitti_odometry" / "sequences" / "00" / "image_0"
    cells = TemplateViewCells()

    def template(i: int) -> np.ndarray:
        return cells.template_from_image(cv2.imread(str(seq / f"{i:06d}.png"), cv2.IMREAD_GRAYSCALE))

    first = cells.observe(template(0))
    assert first.is_new
    near = cells.best_match(template(1))
    far = cells.best_match(template(150))
    assert near is not None and far is not None
    assert near[1] < cells.config.novelty_threshold < far[1]


@pytest.mark.data
def test_rtabmap_loop_revisits_are_closer_than_other_pairs(shared_data) -> None:
    root = shared_data / "rtabmap_loop_samples"
    files = sorted(root.glob("*.jpg"), key=lambda p: int(p.stem))
    truth = cv2.imread(str(root / "samples_GT.bmp"), cv2.IMREAD_GRAYSCALE) > 0
    truth |= truth.T
    cells = TemplateViewCells(TemplateViewConfig(crop_rows_frac=(0.0, 1.0)))
    templates = [cells.template_from_image(cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)) for f in files]
    for t in templates:
        cells.add(t)
    d = np.stack([cells.differences(t)[0] for t in templates])
    n = len(files)
    i, j = np.triu_indices(n, k=4)  # skip temporal neighbours
    revisit, other = d[i, j][truth[i, j]], d[i, j][~truth[i, j]]
    # Probability that a revisit pair is closer than a non-revisit pair (ROC AUC). Measured 0.64 with the
    # defaults: handheld views of a corridor change a lot between visits, so whole-image templates separate
    # revisits only weakly here; the bound guards against regressions towards chance (0.5).
    auc = float((revisit[:, None] < other[None, :]).mean())
    assert auc > 0.6, auc


@pytest.mark.data
def test_rtabmap_loop_precision_and_recall(shared_data) -> None:
    """Observe the 84 handheld corridor images in order; a familiar view matched to a cell made `gap` or more
    images earlier is a loop claim, correct when the ground truth says the two images are a revisit."""
    root = shared_data / "rtabmap_loop_samples"
    if not (root / "samples_GT.bmp").is_file():
        pytest.skip(f"{root} not found")
    files = sorted(root.glob("*.jpg"), key=lambda p: int(p.stem))
    assert len(files) == 84
    truth = (
        cv2.imread(str(root / "samples_GT.bmp"), cv2.IMREAD_GRAYSCALE) > 0
    )  # truth[i, j]: i revisits j < i
    assert truth.shape == (84, 84) and not np.triu(truth).any()
    cells = TemplateViewCells()
    created_at: dict[int, int] = {}
    claims, correct, gap = [], [], 5
    for i, f in enumerate(files):
        obs = cells.observe(cells.template_from_image(cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)))
        if obs.is_new:
            created_at[obs.cell_id] = i
        elif obs.status == "familiar" and i - created_at[obs.cell_id] >= gap:
            j = created_at[obs.cell_id]
            claims.append((i + 1, j + 1))
            correct.append(bool(truth[i, j]))
    precision = sum(correct) / max(len(claims), 1)
    recall = sum(correct) / int(truth.any(axis=1).sum())  # revisit images with a correct claim / 44
    print(f"rtabmap: {len(cells)} cells, claims {claims}, precision {precision:.2f}, recall {recall:.3f}")
    # Measured with the defaults: 79 cells; 3 loop claims (56→16, 58→18, 64→24), all correct: precision 1.0,
    # recall 3/44 = 0.07. Whole-image templates barely recognise handheld views of a corridor (best
    # differences of true revisits are 0.32–0.67, mostly above the 0.45 threshold); raising the threshold
    # trades precision away (0.5: 5/6 correct, 0.55: 9/16, 0.6: 14/42). What is guarded here is that the
    # default threshold makes no false loop closures on real images while still finding some revisits.
    assert len(claims) >= 2 and sum(correct) >= 2, claims
    assert precision >= 0.75, claims
