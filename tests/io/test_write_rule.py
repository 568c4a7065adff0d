"""One rule for every file the package writes: through `hippo_nav.io.atomic` (whole or not at all, never
through a link planted at its name). This test reads the package's source and fails on any other write, so
a new writer cannot slip past the rule: a plain `open(..., "w")`, `Path.write_text`, `np.save…`,
`cv2.imwrite`, `savefig`, `shutil.copy…` or `os.open` anywhere but `io/atomic.py`. (Renaming a whole file
into place writes no content and is not a write here.)

A writer call that takes a file object or a temporary path is allowed when that name comes from
`open_atomic(...)` / `atomic_path(...)` (`with ... as f`) or is an in-memory buffer (`io.BytesIO()`).
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[2] / "python" / "hippo_nav"

WRITER_FUNCTIONS = {
    ("np", "save"), ("np", "savez"), ("np", "savez_compressed"), ("np", "savetxt"), ("cv2", "imwrite"),
    ("shutil", "copy"), ("shutil", "copy2"), ("shutil", "copyfile"), ("shutil", "copytree"), ("shutil", "move"),
    ("os", "open"), ("os", "link"), ("os", "symlink"),
}  # fmt: skip
"""Module functions that write a file; their first argument must be an allowed target (module doc)."""
WRITER_METHODS = {
    "write_text",
    "write_bytes",
    "savefig",
    "tofile",
    "to_csv",
    "touch",
    "symlink_to",
    "hardlink_to",
}
SAFE_SOURCES = {"open_atomic", "atomic_path", "BytesIO", "StringIO"}
"""A name bound from one of these (with ... as NAME, or NAME = ...) may be written to."""

ALLOWED = {
    ("sweep/manifest.py", "write_text"): "writes to /proc/self/clear_refs (a kernel control file, no data)",
}
"""(module, call) pairs that are not data files, with the reason."""


def _name(node: ast.expr) -> str | None:
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        return node.attr
    return None


def _safe_names(tree: ast.AST) -> set[str]:
    safe: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.With):
            for item in node.items:
                call = item.context_expr
                if (
                    isinstance(call, ast.Call)
                    and _name(call.func) in SAFE_SOURCES
                    and isinstance(item.optional_vars, ast.Name)
                ):
                    safe.add(item.optional_vars.id)
        elif (
            isinstance(node, ast.Assign)
            and isinstance(node.value, ast.Call)
            and _name(node.value.func) in SAFE_SOURCES
        ):
            safe |= {t.id for t in node.targets if isinstance(t, ast.Name)}
    return safe


def _mode(call: ast.Call, position: int) -> str | None:
    """The literal mode of an open() call ("r" when absent), or None when it is not a literal."""
    node = next((k.value for k in call.keywords if k.arg == "mode"), None)
    if node is None and len(call.args) > position:
        node = call.args[position]
    if node is None:
        return "r"
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value
    return None


def _violations(path: Path, rel: str) -> list[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    safe = _safe_names(tree)
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        func = node.func
        what = None
        if isinstance(func, ast.Name) and func.id == "open":
            mode = _mode(node, 1)
            if mode is None or set(mode) & set("wax+"):
                what = f"open(..., {mode!r})"
        elif isinstance(func, ast.Attribute):
            owner = _name(func.value)
            if func.attr == "open" and owner not in ("os", "tarfile", "zipfile", "Image"):
                mode = _mode(node, 0)
                if mode is None or set(mode) & set("wax+"):
                    what = f".open({mode!r})"
            elif (owner, func.attr) in WRITER_FUNCTIONS:
                target = node.args[0] if node.args else None
                if not (isinstance(target, ast.Name) and target.id in safe):
                    what = f"{owner}.{func.attr}"
            elif func.attr in WRITER_METHODS and owner != "atomic":
                target = node.args[0] if func.attr in ("savefig", "tofile", "to_csv") and node.args else None
                if not (isinstance(target, ast.Name) and target.id in safe):
                    what = f".{func.attr}"
        if what is not None and (rel, what.strip(".").split("(")[0]) not in ALLOWED:
            found.append((node.lineno, f"{rel}:{node.lineno}: {what}"))
    return [text for _, text in sorted(found)]


def test_every_file_the_package_writes_goes_through_the_atomic_writer():
    sources = sorted(p for p in PACKAGE.rglob("*.py") if p.relative_to(PACKAGE).as_posix() != "io/atomic.py")
    assert len(sources) > 50
    violations = [v for p in sources for v in _violations(p, p.relative_to(PACKAGE).as_posix())]
    assert not violations, (
        "write these through hippo_nav.io.atomic (open_atomic, write_text, write_bytes, atomic_path, "
        "open_lock):\n" + "\n".join(violations)
    )


def test_the_rule_sees_the_writes_it_forbids(tmp_path):
    """The scanner is not blind: each forbidden form is found, each allowed form is not."""
    module = tmp_path / "probe.py"
    source = (
        "import numpy as np\nfrom pathlib import Path\nfrom hippo_nav.io.atomic import open_atomic\n"
        "def bad(p, a, figure):\n"
        "    open(p, 'w').write('x')\n"
        "    Path(p).write_text('x')\n"
        "    np.save(p, a)\n"
        "    figure.savefig(p)\n"
        "    with Path(p).open('a') as f:\n"
        "        f.write('x')\n"
        "def good(p, a, figure):\n"
        "    open(p).read()\n"
        "    with open_atomic(p, 'wb') as f:\n"
        "        np.save(f, a)\n"
    )
    module.write_text(source, encoding="utf-8")
    found = _violations(module, "probe.py")
    assert [v.split(": ", 1)[1] for v in found] == [
        "open(..., 'w')",
        ".write_text",
        "np.save",
        ".savefig",
        ".open('a')",
    ]
