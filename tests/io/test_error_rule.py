"""One rule for operating-system errors in messages: in words, naming the file (`os_error_words`), never
Python's `[Errno 2] No such file or directory: '…'`. This test reads the package's source and fails where a
handler of `OSError` puts the error itself into a message (`f"...{err}"`, `str(err)`), so a new reader
cannot bring the raw text back; and the command line's last resort turns any `OSError` into words."""

from __future__ import annotations

import ast
from pathlib import Path

from hippo_nav.cli import main
from hippo_nav.io.errors import os_error_words

PACKAGE = Path(__file__).resolve().parents[2] / "python" / "hippo_nav"


def _catches_os_error(handler: ast.ExceptHandler) -> bool:
    kinds = handler.type.elts if isinstance(handler.type, ast.Tuple) else [handler.type]
    names = {k.id if isinstance(k, ast.Name) else getattr(k, "attr", None) for k in kinds if k is not None}
    return bool(names & {"OSError", "IOError", "EnvironmentError", "PermissionError", "FileNotFoundError"})


def _raw_uses(handler: ast.ExceptHandler) -> list[int]:
    """Lines in the handler where its error is formatted as it is (not through a function of it)."""
    name = handler.name
    lines = []
    for node in ast.walk(ast.Module(body=handler.body, type_ignores=[])):
        if (
            isinstance(node, ast.FormattedValue)
            and isinstance(node.value, ast.Name)
            and node.value.id == name
        ) or (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Name)
            and node.func.id in ("str", "repr")
            and node.args
            and isinstance(node.args[0], ast.Name)
            and node.args[0].id == name
        ):
            lines.append(node.lineno)
    return lines


def _violations(path: Path, rel: str) -> list[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ExceptHandler) and node.name and _catches_os_error(node):
            found += [f"{rel}:{line}" for line in _raw_uses(node)]
    return sorted(found)


def test_no_message_carries_an_os_errors_raw_text():
    sources = sorted(PACKAGE.rglob("*.py"))
    violations = [v for p in sources for v in _violations(p, p.relative_to(PACKAGE).as_posix())]
    assert not violations, "format OSErrors with hippo_nav.io.errors.os_error_words:\n" + "\n".join(
        violations
    )


def test_the_rule_sees_raw_os_errors(tmp_path):
    probe = tmp_path / "probe.py"
    probe.write_text(
        "def f(p):\n"
        "    try:\n        open(p)\n    except OSError as err:\n        raise ValueError(f'bad {err}')\n"
        "    try:\n        open(p)\n    except (KeyError, PermissionError) as e:\n        print(str(e))\n"
        "    try:\n        open(p)\n    except OSError as err:\n        raise ValueError(words(err))\n"
    )
    assert _violations(probe, "probe.py") == ["probe.py:5", "probe.py:9"]


def test_os_errors_read_as_words_naming_the_file(tmp_path, capsys):
    try:
        (tmp_path / "absent.json").read_text()
    except OSError as err:
        words = os_error_words(err)
    assert words == f"no such file or directory: {tmp_path / 'absent.json'}" and "[Errno" not in words
    # The command line's last resort: an OSError from anywhere is one line in words.
    folder = tmp_path / "a_folder.json"
    folder.mkdir()
    assert main(["run", "--config", str(folder), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("hippo-nav: error:") and "\n" not in err and "[Errno" not in err
