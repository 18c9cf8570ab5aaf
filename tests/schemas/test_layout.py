from pathlib import Path

from schemas import dataset_recordings, is_recording


def test_dataset_recordings_skip_salvaged_and_unfinished_files(tmp_path: Path) -> None:
    names = [
        "wood/P1/001.mcap",
        "wood/P1/002.mcap",
        "wood/P1/003.1234-ab.mcap.part",
        "wood/P1/003.1234-ab.recovered.mcap",
        "wood/P1/notes.txt",
    ]
    for name in names:
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_bytes(b"")
    found = [p.relative_to(tmp_path).as_posix() for p in dataset_recordings(tmp_path)]
    assert found == ["wood/P1/001.mcap", "wood/P1/002.mcap"]
    assert not is_recording(Path("x.recovered.mcap"))
    assert is_recording(Path("x.mcap"))
