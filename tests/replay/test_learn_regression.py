"""A short learning run over the committed recordings reproduces its golden decisions.

Regenerate the golden (with the recordings) by ``python recordings/regenerate.py``.
"""

import json
import math
from pathlib import Path
from types import ModuleType

from scripts import load_script

RECORDINGS = Path(__file__).resolve().parents[2] / "recordings"


def _regenerate_module() -> ModuleType:
    return load_script(RECORDINGS / "regenerate.py", "regenerate")


def test_learning_run_matches_its_golden() -> None:
    regenerate = _regenerate_module()
    golden = json.loads((RECORDINGS / "learn.golden.json").read_text())
    rows = regenerate.learn_summary(regenerate.regression_run(RECORDINGS / "data"))
    assert len(rows) == len(golden) == regenerate.LEARN_BUDGET + 1
    for row, expected in zip(rows, golden, strict=True):
        assert row.keys() == expected.keys()
        for key, value in expected.items():
            if isinstance(value, float):
                assert math.isclose(row[key], value, rel_tol=1e-9, abs_tol=1e-12), (key, row)
            else:
                assert row[key] == value, (key, row)


def test_regression_run_transfers_and_explores() -> None:
    golden = json.loads((RECORDINGS / "learn.golden.json").read_text())
    assert any(row["prior"] for row in golden), "the golden run should transfer some prior"
    assert {row["action"] for row in golden[1:]} == {"P2", "S2"}
    assert golden[-1]["accuracy"] >= golden[0]["accuracy"]
