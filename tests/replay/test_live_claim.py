"""A live run's claim of its directory is taken back only when the run recorded nothing."""

from __future__ import annotations

from typing import TYPE_CHECKING

from replay.live import claim_live_run, release_unused_claim

if TYPE_CHECKING:
    from pathlib import Path

SETTINGS = {"rig": {"name": "sim-ur10", "host": "127.0.0.1"}, "budget": 3}


def test_a_claim_without_recordings_is_taken_back_and_the_directory_stays(tmp_path: Path) -> None:
    target = tmp_path / "live"
    assert claim_live_run(target, SETTINGS) is False
    (target / "session" / "wood").mkdir(parents=True)
    assert release_unused_claim(target, SETTINGS)
    assert target.is_dir()
    assert list(target.iterdir()) == []
    # another configuration can claim it now
    assert claim_live_run(target, {**SETTINGS, "rig": {"name": "sim-ur10", "host": "::1"}}) is False


def test_a_claim_with_anything_recorded_stays(tmp_path: Path) -> None:
    target = tmp_path / "live"
    claim_live_run(target, SETTINGS)
    part = target / "session" / "wood" / "P1" / "001.mcap.part"
    part.parent.mkdir(parents=True)
    part.write_bytes(b"\x89MCAP0\r\n")
    assert not release_unused_claim(target, SETTINGS)
    assert (target / "live.json").is_file()
    assert part.read_bytes() == b"\x89MCAP0\r\n"


def test_another_runs_claim_is_never_taken_back(tmp_path: Path) -> None:
    target = tmp_path / "live"
    claim_live_run(target, SETTINGS)
    assert not release_unused_claim(target, {**SETTINGS, "budget": 4})
    assert (target / "live.json").is_file()
