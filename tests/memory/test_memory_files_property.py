"""A saved memory that is not what this package writes — a malformed manifest, arrays of another shape,
parts mixed from several runs, another camera — is one `SavedMemoryError` naming the folder and what is
wrong, raised before the run starts; never a traceback from inside a part, never a map that loads and
then silently never relocalises. The checksums are re-made after each change, so these reach the checks
behind them (a damaged file is caught by its checksum: tests/memory/test_memory.py)."""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from conftest import QUIET
from hippo_nav._core import HippoNavError
from hippo_nav.cli import main
from hippo_nav.memory import SavedMemoryError, read_memory
from hippo_nav.pipeline import SlamSystem, config_from_dict, run
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

FRAMES = 10


@pytest.fixture(scope="module")
def saved(demo, tmp_path_factory) -> Path:
    """A memory of the demo's first frames, and one of a longer run (`saved.parent / "long"`)."""
    root = tmp_path_factory.mktemp("memories")
    config = config_from_dict(QUIET)
    run(root / "short", config=config, progress=False, stop=FRAMES)
    run(root / "long", config=config, progress=False, stop=3 * FRAMES)
    return root / "short"


def _load(folder: Path, demo, resume: bool = False) -> SlamSystem:
    return SlamSystem(demo.calibration, config_from_dict(QUIET), memory=read_memory(folder), resume=resume)


def _copy(folder: Path) -> Path:
    into = Path(tempfile.mkdtemp(prefix="memory-")) / "run"
    shutil.copytree(folder / "memory", into / "memory")
    return into


def _reseal(run_folder: Path) -> None:
    """Make the manifest's sizes and checksums fit the files again (as a careful forger would)."""
    memory = run_folder / "memory"
    manifest = json.loads((memory / "memory.json").read_text())
    for name in manifest["files"]:
        data = (memory / name).read_bytes()
        manifest["files"][name] = {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}
    (memory / "memory.json").write_text(json.dumps(manifest))


def _rewrite_npz(path: Path, change) -> None:
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    change(arrays)
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    path.write_bytes(buffer.getvalue())


def test_the_saved_memories_load(saved, demo):
    assert len(_load(saved, demo).map) > 0
    assert len(_load(saved.parent / "long", demo, resume=True).map) > 0


def test_view_cells_anchored_to_vertices_the_map_lacks_are_refused(saved, demo):
    """views.npz of a longer run beside the short run's map: it would load and never relocalise."""
    mixed = _copy(saved)
    shutil.copy(saved.parent / "long" / "memory" / "views.npz", mixed / "memory" / "views.npz")
    _reseal(mixed)
    with pytest.raises(SavedMemoryError, match="parts disagree.*map vertices|promises"):
        _load(mixed, demo)


def test_keyframes_of_vertices_the_map_lacks_are_refused(saved, demo):
    mixed = _copy(saved)
    _rewrite_npz(mixed / "memory" / "keyframes.npz", lambda a: a.update(vertex=a["vertex"] + 1000))
    _reseal(mixed)
    with pytest.raises(SavedMemoryError, match=r"keyframes.npz vertex refers to ids \d+ to \d+"):
        _load(mixed, demo)


@pytest.mark.parametrize(
    "file, change",
    [
        ("state.npz", lambda a: a.pop("vo_pose")),
        ("state.npz", lambda a: a.update({"engine.place": np.zeros(3)})),
        ("views.npz", lambda a: a.update({"recall.stored_sizes": np.array([], np.int64)})),
        ("views.npz", lambda a: a.pop("cells.count")),
        ("keyframes.npz", lambda a: a.update(count=a["count"] * 2)),
    ],
)
def test_arrays_of_another_shape_or_missing_are_one_error(saved, demo, file, change):
    bad = _copy(saved)
    _rewrite_npz(bad / "memory" / file, change)
    _reseal(bad)
    with pytest.raises(SavedMemoryError, match="saved memory in"):
        _load(bad, demo, resume=True)


def test_another_camera_is_named_by_its_image_size_and_focal_length(saved, demo):
    """Not "baseline_m differs by 0.15 mm": the camera as a person compares two."""
    smaller = dataclasses.replace(
        demo.calibration,
        P0=demo.calibration.P0 * np.array([[0.9], [0.9], [1.0]]),
        image_size_px=(demo.calibration.image_size_px[0] - 16, demo.calibration.image_size_px[1] - 8),
    )
    with pytest.raises(SavedMemoryError) as caught:
        SlamSystem(smaller, config_from_dict(QUIET), memory=read_memory(saved))
    message = str(caught.value)
    width, height = demo.calibration.image_size_px
    assert "another camera" in message and f"{width}×{height} px" in message and f"{width - 16}×" in message
    assert f"fx {demo.calibration.fx:.2f} px" in message


JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**70), 2**70) | st.floats() | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=6), inner, max_size=3),
    max_leaves=8,
)
MANIFEST_PATHS = [
    ("version",), ("files",), ("files", "map.bin"), ("files", "views.npz", "bytes"),
    ("files", "state.npz", "sha256"), ("depends_on",), ("depends_on", "camera"),
    ("depends_on", "camera", "image_size_px"), ("depends_on", "engine"), ("counts",), ("counts", "vertices"),
    ("config",), ("odometry",), ("odometry", "disparity_offset_px"), ("odometry", "disparity_offset_frames"),
]  # fmt: skip


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(where=st.sampled_from(MANIFEST_PATHS), value=JSON_VALUES)
def test_any_malformed_manifest_field_is_one_error_or_harmless(saved, demo, where, value):
    bad = _copy(saved)
    manifest_path = bad / "memory" / "memory.json"
    manifest = json.loads(manifest_path.read_text())
    node = manifest
    for key in where[:-1]:
        node = node[key]
    node[where[-1]] = value
    manifest_path.write_text(json.dumps(manifest))
    try:
        _load(bad, demo)
    except HippoNavError as err:
        assert "\n" not in str(err) and str(bad) in str(err)
    finally:
        shutil.rmtree(bad.parent)


def test_a_deeply_nested_manifest_is_one_error(saved, tmp_path, capsys):
    bad = _copy(saved)
    (bad / "memory" / "memory.json").write_text("[" * 100_000 + "]" * 100_000)
    assert (
        main(["run", "--no-progress", "--no-figures", "--map", str(bad), "--out", str(tmp_path / "o")]) == 2
    )
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "nested too deeply" in err and not (tmp_path / "o").exists()
