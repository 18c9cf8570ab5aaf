"""What an import did (the report, as a table and as JSON) and which bags a dataset holds.

Every import writes ``<out>/imports/<id>.json``: the bags by name and content hash (SHA-256),
the map, the recordings written, the windows skipped and why, and the alignment figures. Those
files are the dataset's manifest of imports: a bag whose hash is listed there was imported
already, whatever its name now.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from recorder.errors import BagImportError
from schemas import atomic_write_text

if TYPE_CHECKING:
    from collections.abc import Sequence

    from recorder.bagimport._pack import Rows

#: Directory of a dataset that holds one JSON report per import.
IMPORTS_DIR = "imports"
_CHUNK = 1 << 20


@dataclass(frozen=True, slots=True)
class BagIdentity:
    """A bag by name and content.

    Attributes:
        path: The bag (file or ROS 2 directory).
        sha256: SHA-256 of its content (of its files' names and hashes for a directory).
        size_bytes: Total size.
    """

    path: Path
    sha256: str
    size_bytes: int


def _file_hash(path: Path) -> str:
    with path.open("rb") as handle:
        return hashlib.file_digest(handle, "sha256").hexdigest()


def bag_identity(path: Path) -> BagIdentity:
    """Return a bag's identity (its content hash; a directory hashes its files in order).

    Raises:
        BagImportError: The bag cannot be read.
    """
    path = Path(path)
    try:
        if path.is_dir():
            files = sorted(p for p in path.rglob("*") if p.is_file())
            digest = hashlib.sha256()
            for file in files:
                digest.update(f"{file.relative_to(path).as_posix()}\0{_file_hash(file)}\n".encode())
            return BagIdentity(path, digest.hexdigest(), sum(f.stat().st_size for f in files))
        return BagIdentity(path, _file_hash(path), path.stat().st_size)
    except OSError as err:
        msg = f"{path}: cannot read the bag ({err.strerror}); check the path"
        raise BagImportError(msg) from err


def imported_bags(out: Path) -> dict[str, str]:
    """Return sha256 -> report file of every bag imported into ``out`` before."""
    found: dict[str, str] = {}
    for report in sorted((Path(out) / IMPORTS_DIR).glob("*.json")):
        try:
            data = json.loads(report.read_text("utf-8"))
            for bag in data.get("bags", []):
                found[str(bag["sha256"])] = report.name
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as err:
            msg = f"{report}: not an import report ({err}); restore or delete it"
            raise BagImportError(msg) from err
    return found


def window_key(object_id: str, action_id: str, events: Sequence[tuple[str, int]]) -> str:
    """Return a window's identity in an import report: object, action and phase stamps.

    The trial is not part of it: the same window in a corrected table (a trial number added
    or removed) is the same action, imported once.
    """
    return f"{object_id}/{action_id} " + " ".join(f"{phase}@{stamp}" for phase, stamp in events)


def earlier_import(path: Path) -> tuple[dict[str, str], bool]:
    """Return the windows an earlier import of the same bags wrote, and whether it finished.

    Returns:
        (window key -> recording relative to ``out``, finished); ``({}, True)`` when there
        is no report (a report of an older version lists no windows: finished).

    Raises:
        BagImportError: The report is not one.
    """
    try:
        data = json.loads(path.read_text("utf-8"))
        imported = {str(k): str(v) for k, v in dict(data.get("imported", {})).items()}
        return imported, bool(data.get("complete", True))
    except FileNotFoundError:
        return {}, True
    except (OSError, ValueError, TypeError, AttributeError) as err:
        msg = f"{path}: not an import report ({err}); restore or delete it"
        raise BagImportError(msg) from err


@dataclass(slots=True)
class ImportReport:
    """What an import did.

    Attributes:
        bags: The bags, with their content hashes.
        out: The dataset directory.
        topic_map: The map used.
        written: The recordings written, in window order.
        skipped: Windows not written, with the reason.
        messages: Messages read per bag name.
        dropped_rows: Skin rows dropped (a cell without a sample near the row, a non-finite
            value, a repeated stamp), per modality.
        dropped_samples: Joint states and poses dropped (repeated stamp, non-finite value).
        max_cell_offset_ns: Largest time offset of an aligned cell sample, per modality.
        max_jitter_ns: Largest deviation of a stamp from its block's grid, per modality.
        index: The rebuilt dataset index.
        json_path: Where the report was written as JSON.
        already_imported: Bags skipped because ``out`` holds them already.
        repeated_stamps: Skin messages dropped because they repeat the previous stamp.
        late_samples: Live: samples per topic that arrived after their window was written.
        incomplete: Live: actions kept as incomplete recordings (cut, joined part-way, or
            open at the stop).
        oversize: Live: messages per topic dropped for their size (``max_message_kib``).
        overflowed: Live: messages per topic its reader's full queue dropped.
        interrupted: Live: the signal that stopped the run (``SIGINT``, ``SIGTERM``; empty:
            it ran to its end).
        timing: Per topic and modality stamped by rate (``timing = "rate"``): runs, gaps,
            lost frames, the jitter of the message stamps around the fitted timeline (ms) and
            the drift of the sensor's rate against the stamps' clock (ppm).
        counted: Per topic stamped by its messages whose counter the map names (``timing =
            "message"`` with ``counter``): messages, lost (the counter's skips), duplicated
            and resets.
        lost_samples: Live: per recording whose sources lost samples (``check`` fails it),
            what they lost (e.g. ``/skin/force_1: 3 of 500 missing``).
        cut_short: Live: per recording whose skin does not cover its action (a cell that
            went silent), why: it is kept as incomplete.
        imported: Every window of these bags in ``out`` (:func:`window_key` -> its recording,
            relative to ``out``), this run's and earlier runs': a rerun skips them.
        resumed: The recordings of :attr:`written` that an earlier, stopped run wrote.
        complete: False while the import runs (the report is its progress so far).
        gaps: Pauses of the skin inside the windows written, per modality (a step between
            stamps longer than ``listen`` allows: without a counter, loss or a pause).
        gap_ns: Their total length beyond one period each, per modality.
        malformed: Messages per topic not kept because they are malformed (a joint state
            whose velocities or efforts number other than its names).
    """

    bags: Sequence[BagIdentity]
    out: Path
    topic_map: Path
    written: list[Path] = field(default_factory=list)
    skipped: list[tuple[str, str]] = field(default_factory=list)
    messages: dict[str, int] = field(default_factory=dict)
    dropped_rows: dict[str, int] = field(default_factory=dict)
    dropped_samples: dict[str, int] = field(default_factory=dict)
    max_cell_offset_ns: dict[str, int] = field(default_factory=dict)
    max_jitter_ns: dict[str, int] = field(default_factory=dict)
    index: Path | None = None
    json_path: Path | None = None
    already_imported: dict[str, str] = field(default_factory=dict)
    repeated_stamps: int = 0
    late_samples: dict[str, int] = field(default_factory=dict)
    incomplete: list[Path] = field(default_factory=list)
    oversize: dict[str, int] = field(default_factory=dict)
    overflowed: dict[str, int] = field(default_factory=dict)
    interrupted: str = ""
    timing: dict[str, dict[str, dict[str, Any]]] = field(default_factory=dict)
    counted: dict[str, dict[str, int]] = field(default_factory=dict)
    lost_samples: dict[Path, str] = field(default_factory=dict)
    cut_short: dict[Path, str] = field(default_factory=dict)
    imported: dict[str, str] = field(default_factory=dict)
    resumed: list[Path] = field(default_factory=list)
    complete: bool = True
    malformed: dict[str, int] = field(default_factory=dict)
    gaps: dict[str, int] = field(default_factory=dict)
    gap_ns: dict[str, int] = field(default_factory=dict)

    @property
    def bag(self) -> Path:
        """Return the first bag (single-bag imports)."""
        return self.bags[0].path

    def note(self, modality: str, rows: Rows, jitter_ns: int, dropped: int) -> None:
        """Add one window's alignment figures of a modality."""
        self.dropped_rows[modality] = self.dropped_rows.get(modality, 0) + rows.dropped + dropped
        offset = max(self.max_cell_offset_ns.get(modality, 0), rows.max_offset_ns)
        self.max_cell_offset_ns[modality] = offset
        self.max_jitter_ns[modality] = max(self.max_jitter_ns.get(modality, 0), jitter_ns)

    def to_json(self) -> dict[str, Any]:
        """Return the report as plain JSON data (paths relative to ``out`` where inside)."""
        return {
            "bags": [
                {"name": b.path.name, "sha256": b.sha256, "size_bytes": b.size_bytes}
                for b in self.bags
            ],
            "topic_map": self.topic_map.name,
            "written": [_relative(p, self.out) for p in self.written],
            "skipped": [{"window": w, "reason": r} for w, r in self.skipped],
            "messages": self.messages,
            "dropped_rows": self.dropped_rows,
            "dropped_samples": self.dropped_samples,
            "max_cell_offset_ns": self.max_cell_offset_ns,
            "max_jitter_ns": self.max_jitter_ns,
            "repeated_skin_stamps": self.repeated_stamps,
            **({"late_samples": self.late_samples} if self.late_samples else {}),
            **({"incomplete": [str(p) for p in self.incomplete]} if self.incomplete else {}),
            **({"oversize": self.oversize} if self.oversize else {}),
            **({"overflowed": self.overflowed} if self.overflowed else {}),
            **({"timing": self.timing} if self.timing else {}),
            **({"counted": self.counted} if self.counted else {}),
            **(
                {"lost_samples": {_relative(p, self.out): t for p, t in self.lost_samples.items()}}
                if self.lost_samples
                else {}
            ),
            **({"imported": self.imported} if self.imported else {}),
            **({"malformed": self.malformed} if self.malformed else {}),
            **({"gaps": self.gaps, "gap_ns": self.gap_ns} if self.gaps else {}),
            **({} if self.complete else {"complete": False}),
        }

    @property
    def report_path(self) -> Path:
        """Return where the report goes: ``<out>/imports/<hash of the bags' hashes>.json``."""
        combined = hashlib.sha256("".join(b.sha256 for b in self.bags).encode()).hexdigest()
        return self.out / IMPORTS_DIR / f"{combined[:16]}.json"

    def save(self, *, replace: bool = False) -> Path:
        """Write the report to :attr:`report_path` atomically.

        Args:
            replace: Replace a report there (an import's progress, or the report of an
                earlier import of the same bags that this one continues); otherwise an
                existing report is never replaced.

        Raises:
            BagImportError: The file cannot be written.
        """
        path = self.report_path
        text = json.dumps(self.to_json(), indent=2, sort_keys=True) + "\n"
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_text(path, text, replace=replace)
        except OSError as err:
            msg = f"{path}: cannot write the import report ({err.strerror}); check --out"
            raise BagImportError(msg) from err
        self.json_path = path
        return path


def _relative(path: Path, root: Path) -> str:
    try:
        return path.relative_to(root).as_posix()
    except ValueError:
        return str(path)
