"""Only ``replay/live/`` uses the recorder, and never a private module of it."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
HOME = "replay/live/"


def recorder_imports(tree: ast.AST) -> list[tuple[int, str]]:
    """Return (line, module) of every import of ``recorder`` or one of its modules."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            modules = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            modules = [node.module]
        else:
            continue
        found += [(node.lineno, m) for m in modules if m.split(".")[0] == "recorder"]
    return found


def test_the_scan_finds_imports_of_the_recorder() -> None:
    tree = ast.parse("import recorder\nif x:\n    from recorder._sim.rig import V\nimport rec\n")
    assert recorder_imports(tree) == [(1, "recorder"), (3, "recorder._sim.rig")]


def test_only_the_live_package_imports_the_recorder_and_only_its_public_api() -> None:
    outside, private = [], []
    for path in sorted((ROOT / "replay").rglob("*.py")):
        relative = path.relative_to(ROOT).as_posix()
        for line, module in recorder_imports(ast.parse(path.read_text("utf-8"))):
            if not relative.startswith(HOME):
                outside.append(f"{relative}:{line}: {module}")
            if module != "recorder":
                private.append(f"{relative}:{line}: {module}")
    assert outside == [], "use replay.live for everything that needs the recorder"
    assert private == [], "import from recorder's public API (recorder.__all__)"
    assert any((ROOT / HOME).glob("*.py"))
