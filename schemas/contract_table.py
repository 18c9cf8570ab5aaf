"""Write schemas/README.md's contract tables from their one source, ``schemas/contract.toml``.

Run ``python -m schemas.contract_table`` after an edit of the contract; ``--check`` exits 1
when the README's tables differ from the contract (the tests run it), so they cannot drift.
The tables sit between ``<!-- contract:NAME -->`` and ``<!-- /contract:NAME -->`` markers.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from schemas._typestore import VOCABULARY

README = Path(__file__).resolve().parent / "README.md"


def _rows(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def channels_table() -> str:
    """Return the channel table: robot, skin and event channels."""
    rows = []
    for c in VOCABULARY.robot.values():
        frame = f"`{c.frame}`" if c.frame else '`""`'
        rate = f"{c.rate_hz:g} Hz (UR10 CB3 RTDE)"
        rows.append([f"`{c.topic}`", f"`{c.msgtype}`", rate, c.units, frame])
        rows[-1].append(f"optional: {c.description}")
    for m in VOCABULARY.modalities.values():
        rate = f"{m.rate_hz:g} Hz ({m.block_samples} per block)"
        rows.append([f"`{m.topic}`", f"`{m.msgtype}`", rate, m.units, "`skin`"])
        rows[-1].append(f"optional: {m.description}")
    events = VOCABULARY.events
    rows.append([f"`{events.topic}`", f"`{events.msgtype}`", "one per phase", events.units])
    rows[-1] += [f"`{events.frame}`", f"required: {events.description}"]
    return _rows(["topic", "type", "thesis rig's rate", "units", "frame", "role"], rows)


def modalities_table() -> str:
    """Return the modality table: what one value of a cell is, the default names, feature."""
    rows = []
    for m in VOCABULARY.modalities.values():
        feature = f"`{m.feature}`" if m.feature else "-"
        rows.append([f"`{m.name}`", m.value, ", ".join(m.values), m.units, feature])
    return _rows(["modality", "a value is a", "thesis skin's values", "units", "feature"], rows)


def kinds_table() -> str:
    """Return the action-kind table: needed modalities, thesis features, parameters."""
    rows = []
    for k in VOCABULARY.kinds.values():
        rows.append([f"`{k.name}`", ", ".join(k.needs), ", ".join(k.features)])
        rows[-1] += [", ".join(k.parameters), k.description]
    header = ["kind", "needs", "thesis features", "required parameters", "what it does"]
    return _rows(header, rows)


def sources_table() -> str:
    """Return the sources table: the phases each source of recordings promises."""
    rows = [
        [f"`{s.name}`", ", ".join(s.phases), s.description] for s in VOCABULARY.sources.values()
    ]
    return _rows(["source", "phases it promises", "what it is"], rows)


TABLES = {
    "channels": channels_table,
    "modalities": modalities_table,
    "kinds": kinds_table,
    "sources": sources_table,
}


def render(text: str) -> str:
    """Return ``text`` with every marked table replaced by the contract's.

    Raises:
        SystemExit: A marker pair is missing.
    """
    for name, make in TABLES.items():
        pattern = re.compile(
            rf"(<!-- contract:{name} -->\n)(?:.*?\n)?(<!-- /contract:{name} -->)", re.DOTALL
        )
        found = pattern.search(text)
        if found is None:
            sys.exit(
                f"{README}: no <!-- contract:{name} --> ... markers; add them around the table"
            )
        start, stop = found.span()
        text = text[:start] + found.group(1) + make() + "\n" + found.group(2) + text[stop:]
    return text


def main(argv: list[str] | None = None) -> int:
    """Rewrite (or with ``--check`` compare) the README's contract tables."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if the README differs")
    args = parser.parse_args(argv)
    current = README.read_text("utf-8")
    wanted = render(current)
    if args.check:
        if wanted != current:
            print(f"{README}: contract tables differ; run python -m schemas.contract_table")  # noqa: T201
            return 1
        return 0
    README.write_text(wanted, "utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
