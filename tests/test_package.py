import hippo_nav


def test_version_matches_cargo_workspace():
    import tomllib
    from conftest import PROJECT_ROOT

    cargo = tomllib.loads((PROJECT_ROOT / "Cargo.toml").read_text())
    assert hippo_nav.__version__ == cargo["workspace"]["package"]["version"]


def test_error_is_a_value_error():
    assert issubclass(hippo_nav.HippoNavError, ValueError)
