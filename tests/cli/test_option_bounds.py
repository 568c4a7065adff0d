"""Every numeric option of every command has explicit bounds (`hippo_nav.cli.common.bounded_int`): a value out
of range, a fraction, text or 10**30 is argparse's one error line naming the option and the range, exit 2,
before anything runs (it used to reach NumPy or Rust and end in a traceback)."""

from __future__ import annotations

import argparse

import pytest
from hippo_nav.cli import build_parser, main
from hypothesis import given, settings
from hypothesis import strategies as st


def _commands() -> dict[str, argparse.ArgumentParser]:
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def _bounded_options() -> list[tuple[str, str, int, int]]:
    """(command, option, lo, hi) of every option whose type is a `bounded_int`."""
    found = []
    for name, parser in _commands().items():
        for action in parser._actions:
            label = getattr(action.type, "__name__", "")
            if label.startswith("integer from "):
                lo, hi = (int(x) for x in label.removeprefix("integer from ").split(" to "))
                found.append((name, action.option_strings[0], lo, hi))
    return found


OPTIONS = _bounded_options()


def test_no_numeric_option_is_left_unbounded():
    """A bare `type=int` or `type=float` takes 10**30, -5 or nan; every numeric option names its range."""
    bare = [
        f"{name} {action.option_strings}"
        for name, parser in _commands().items()
        for action in parser._actions
        if action.type in (int, float)
    ]
    assert not bare, f"give these a bounded type (cli.common.bounded_int): {bare}"
    found = {(name, option) for name, option, _, _ in OPTIONS}
    assert {
        ("run", "--start"), ("run", "--stop"), ("run", "--stride"), ("run", "--seed"), ("run", "--video-every"),
        ("render", "--start"), ("render", "--stop"), ("render", "--seed"), ("render", "--workers"),
        ("sweep", "--stride"), ("sweep", "--cpus-per-run"), ("sweep", "--workers"), ("sweep", "--retries"),
        ("vocabulary", "--every"), ("vocabulary", "--branching"), ("vocabulary", "--levels"), ("vocabulary", "--seed"),
    } <= found  # fmt: skip


def _refused(capsys: pytest.CaptureFixture[str], argv: list[str]) -> str:
    with pytest.raises(SystemExit) as info:
        build_parser().parse_args(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err  # one line, no usage dump
    return err.strip()


@pytest.mark.parametrize(("command", "option", "lo", "hi"), OPTIONS)
@pytest.mark.parametrize("which", ["below", "above", "huge", "fraction", "text", "nan"])
def test_a_bad_value_is_one_line_naming_the_option_and_its_range(capsys, command, option, lo, hi, which):
    value = {
        "below": str(lo - 1),
        "above": str(hi + 1),
        "huge": str(10**30),
        "fraction": "1.5",
        "text": "many",
        "nan": "nan",
    }[which]
    line = _refused(capsys, [command, f"{option}={value}"])
    assert line.startswith(f"hippo-nav {command}: error: argument {option}")
    assert f"from {lo} to {hi}" in line


@pytest.mark.parametrize(("command", "option", "lo", "hi"), OPTIONS)
def test_the_bounds_themselves_are_accepted(command, option, lo, hi):
    parser = _commands()[command]
    action = next(a for a in parser._actions if option in a.option_strings)
    assert action.type is not None
    assert action.type(str(lo)) == lo and action.type(str(hi)) == hi


@given(
    option=st.sampled_from(OPTIONS),
    value=st.one_of(
        st.integers(min_value=-(10**40), max_value=10**40).map(str),
        st.floats(allow_nan=True, allow_infinity=True).map(repr),
        st.text(max_size=30),
        st.text(alphabet="0123456789", min_size=4000, max_size=6000),  # beyond Python's int("…") limit
    ),
)
@settings(max_examples=80, deadline=None)
def test_any_value_is_parsed_or_refused_in_one_line(option, value):
    command, flag, lo, hi = option
    parser = _commands()[command]
    action = next(a for a in parser._actions if flag in a.option_strings)
    assert action.type is not None
    try:
        parsed = action.type(value)
    except argparse.ArgumentTypeError as err:
        message = str(err)
        assert "\n" not in message and f"from {lo} to {hi}" in message and len(message) < 200
    else:
        assert lo <= parsed <= hi


@pytest.mark.parametrize(
    "size", ["0x5", "320x96x3", "wide", "5000x96", f"{10**30}x96", "1.5x96", "9" * 5000 + "x9"]
)
def test_render_size_is_checked_by_argparse(capsys, size):
    line = _refused(capsys, ["render", f"--size={size}"])
    assert line.startswith("hippo-nav render: error: argument --size") and len(line) < 200


def test_the_command_line_itself_exits_2_with_one_error_line(capsys, tmp_path):
    """Through `main`, as the user runs it: exit 2 and nothing started (no results folder)."""
    out = tmp_path / "run"
    assert main(["run", "--stride", str(10**30), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.strip().splitlines() == [
        (
            "hippo-nav run: error: argument --stride: '1000000000000000000000000000000' is out of range; give "
            "an integer from 1 to 1000000000 (see hippo-nav run --help)"
        )
    ]
    assert not out.exists()
