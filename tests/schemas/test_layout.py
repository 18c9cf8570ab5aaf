import os
from pathlib import Path

from schemas import dataset_recordings, is_recording, part_writer, process_running


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


def test_a_part_names_its_writer_and_a_number_that_is_no_process_is_not_running() -> None:
    assert part_writer(Path(f"001.{os.getpid()}-ab12.mcap.part")) == os.getpid()
    assert process_running(os.getpid())
    assert part_writer(Path("001.mcap.part")) is None
    assert not process_running(None)
    # a copied or hostile name: no traceback (os.kill overflows), no process group (0)
    for number in ("0", "99999999999999999999999", str(2**31)):
        assert not process_running(part_writer(Path(f"001.{number}-ab.mcap.part")))
