"""A short, seeded run of the reader's fuzzer (``tests/fuzz/fuzz_reader.py`` runs it long)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest
from scripts import load_script

if TYPE_CHECKING:
    from types import ModuleType

SCRIPT = Path(__file__).resolve().parents[1] / "fuzz" / "fuzz_reader.py"
ROOT = SCRIPT.parents[2]


@pytest.fixture(scope="module")
def fuzzer() -> ModuleType:
    return load_script(SCRIPT, "fuzz_reader")


def test_mutated_recordings_are_read_or_refused_with_our_error(fuzzer: ModuleType) -> None:
    files = [ROOT / "recordings/data/metal_toolbox/S1/001.mcap"]
    tally = fuzzer.fuzz(800, seed=7, files=files, timeout=10.0, salvage_every=4)
    assert tally.failures == []
    assert tally.mutations == 800
    outcomes = {outcome for (_, outcome) in tally.outcomes}
    assert outcomes == {"valid", "refused"}  # both happen: the mutations are not all fatal
    assert sum(n for (what, _), n in tally.outcomes.items() if what == "salvage") == 200


def test_every_mutation_kind_changes_the_file(fuzzer: ModuleType) -> None:
    corpus = fuzzer.load_corpus([ROOT / "recordings/data/wood/P1/001.mcap"])
    assert len(corpus) == 3
    rng = np.random.default_rng(0)
    for name, mutate in fuzzer.MUTATIONS.items():
        for seed in corpus:
            assert mutate(rng, seed, corpus) != seed.data, name


def test_a_failure_is_reported_with_its_traceback(
    fuzzer: ModuleType, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    def broken(_path: Path) -> None:
        msg = "a bug"
        raise ZeroDivisionError(msg)

    monkeypatch.setattr(fuzzer, "read_recording", broken)
    files = [ROOT / "recordings/data/metal_toolbox/S1/001.mcap"]
    tally = fuzzer.fuzz(3, seed=0, files=files, salvage_every=0, failures=tmp_path)
    assert len(tally.failures) == 3
    assert "ZeroDivisionError: a bug" in tally.failures[0]
    assert len(list(tmp_path.glob("case*.mcap"))) == 3
