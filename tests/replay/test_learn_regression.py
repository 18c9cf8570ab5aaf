"""A short learning run over the committed recordings reproduces its golden decisions.

Regenerate the golden (with the recordings) by ``python recordings/regenerate.py``.
"""

import importlib.util
import json
import math
from pathlib import Path
from types import ModuleType

RECORDINGS = Path(__file__).resolve().parents[2] / "recordings"


def _regenerate_module() -> ModuleType:
    spec = importlib.util.spec_from_file_location("regenerate", RECORDINGS / "regenerate.py")
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


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
