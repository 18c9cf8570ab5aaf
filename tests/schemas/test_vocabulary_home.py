"""The vocabulary lives once: no code outside its homes lists modalities, kinds or phases.

A list, tuple, set or dict literal holding two or more of the contract's names (modalities,
feature blocks, action kinds, phases) is a second copy of the vocabulary that silently misses
the next addition. Allowed: ``schemas/`` (the contract itself), the simulator (its physical
model of each simulated modality and kind) and atikt's feature functions.
"""

from __future__ import annotations

import ast
from pathlib import Path

from schemas import VOCABULARY

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("atikt", "replay", "recorder", "schemas")
# the simulator and the virtual lab's skin model each model every modality's physics
HOMES = ("schemas/", "recorder/_sim/", "recorder/virtuallab/_skinmodel.py", "atikt/features.py")
NAMES = {
    *VOCABULARY.modalities,
    *VOCABULARY.features,
    *VOCABULARY.kinds,
    *VOCABULARY.phases,
}


def listed_names(tree: ast.AST) -> list[tuple[int, list[str]]]:
    """Return (line, names) of every collection literal that holds two or more names."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.List | ast.Tuple | ast.Set):
            items = node.elts
        elif isinstance(node, ast.Dict):
            items = [k for k in node.keys if k is not None]
        else:
            continue
        names = [
            e.value
            for e in items
            if isinstance(e, ast.Constant) and isinstance(e.value, str) and e.value in NAMES
        ]
        if len(names) >= 2:
            found.append((node.lineno, names))
    return found


def test_the_scan_finds_a_list_of_modalities() -> None:
    tree = ast.parse('MODALITIES = ("force", "temperature")\nONE = "force"\n')
    assert listed_names(tree) == [(1, ["force", "temperature"])]


def test_no_code_outside_the_vocabulary_lists_its_names() -> None:
    copies = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            relative = path.relative_to(ROOT).as_posix()
            if relative.startswith(HOMES):
                continue
            copies += [
                f"{relative}:{line}: {names}"
                for line, names in listed_names(ast.parse(path.read_text("utf-8")))
            ]
    assert copies == [], "read these from schemas.VOCABULARY instead:\n" + "\n".join(copies)
