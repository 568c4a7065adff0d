import hippo_nav


def test_version_matches_cargo_workspace():
    import tomllib
    from conftest import PROJECT_ROOT

    cargo = tomllib.loads((PROJECT_ROOT / "Cargo.toml").read_text())
    assert hippo_nav.__version__ == cargo["workspace"]["package"]["version"]


def test_error_is_a_value_error():
    assert issubclass(hippo_nav.HippoNavError, ValueError)


def test_the_pipeline_is_reachable_from_the_package_without_loading_it_on_import():
    import subprocess
    import sys

    code = (
        "import sys, hippo_nav; assert 'cv2' not in sys.modules; hippo_nav.run; assert 'cv2' in sys.modules"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
    import hippo_nav

    result = hippo_nav.run(None, stop=4, progress=False)
    assert result.metrics["frames"] == 4 and result.out_dir is None


def test_native_stubs_match_the_built_module():
    """`_core.pyi` describes the built module exactly (mypy's stubtest; mypy is in the test extra)."""
    import subprocess
    import sys

    import pytest

    pytest.importorskip("mypy")
    command = [sys.executable, "-m", "mypy.stubtest", "hippo_nav._core"]
    done = subprocess.run(command, check=False, capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
