"""Properties of topic maps, window tables and skin packing (hypothesis)."""

from __future__ import annotations

import itertools
from decimal import Decimal
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from recorder.bagimport._pack import Rows, skin_blocks
from recorder.bagimport._topicmap import load_topic_map
from recorder.bagimport._windows import check_no_overlap, windows_from_csv
from recorder.errors import BagImportError
from schemas import VOCABULARY

NS = 10**9
MODALITIES = tuple(VOCABULARY.modalities)
SETTINGS = settings(max_examples=40, deadline=None)


@st.composite
def skin_tables(draw: st.DrawFn) -> tuple[str, dict[str, tuple[int, str | None]]]:
    """Return the [skin] TOML of a random skin and, per modality, (samples, rate text)."""
    chosen = draw(st.sets(st.sampled_from(MODALITIES), min_size=1))
    cells = draw(st.lists(st.integers(0, 999), min_size=1, max_size=8, unique=True))
    text = f"[skin]\ncells = {cells}\n"
    expected: dict[str, tuple[int, str | None]] = {}
    for modality in sorted(chosen):
        samples = draw(st.integers(1, 64))
        rate = None
        if samples > 1 or draw(st.booleans()):
            whole = draw(st.integers(1, 20_000))
            rate = draw(st.sampled_from([str(whole), f"{whole}.{draw(st.integers(0, 999)):03d}"]))
        text += f'\n[skin.{modality}]\ntopic = "/lab/{modality}_{{cell}}"\nfield = "v"\n'
        text += f"samples_per_message = {samples}\n" + (f"rate_hz = {rate}\n" if rate else "")
        expected[modality] = (samples, rate)
    return text, expected


ROBOT = st.sampled_from(["", '[joint_states]\ntopic = "/j"\n', '[tool_pose]\ntopic = "/p"\n'])
WINDOWS = '[windows]\nsource = "topic"\ntopic = "/annotations"\n'


@SETTINGS
@given(skin=skin_tables(), robot=ROBOT)
def test_any_skin_and_robot_parse_with_exact_sample_offsets(
    tmp_path_factory: pytest.TempPathFactory,
    skin: tuple[str, dict[str, tuple[int, str | None]]],
    robot: str,
) -> None:
    text, expected = skin
    path = tmp_path_factory.mktemp("map") / "map.toml"
    path.write_text(robot + text + WINDOWS, encoding="utf-8")
    topic_map = load_topic_map(path)
    assert set(topic_map.skin) == set(expected)
    assert (topic_map.joints is None) == ("joint_states" not in robot)
    for modality, (samples, rate) in expected.items():
        spec = topic_map.skin[modality]
        assert spec.samples_per_message == samples
        offsets = spec.offsets_ns()
        if rate is None:
            assert offsets == (0,)
            continue
        period = Fraction(NS) / Fraction(Decimal(rate))
        assert spec.period_ns == period
        for i, offset in enumerate(offsets):  # exact floor: never later, under 1 ns earlier
            assert 0 <= i * period - offset < 1


@st.composite
def window_tables(draw: st.DrawFn) -> list[tuple[int, int]]:
    """Return (start, stop) ns of random windows, possibly overlapping."""
    count = draw(st.integers(1, 8))
    starts = draw(st.lists(st.integers(0, 10**12), min_size=count, max_size=count))
    return [(s, s + draw(st.integers(1, 10 * NS))) for s in starts]


def _seconds(ns: int) -> str:
    return f"{ns // NS}.{ns % NS:09d}"


@SETTINGS
@given(table=window_tables(), unit=st.sampled_from(["s", "ns"]))
def test_window_tables_parse_exactly_and_refuse_overlaps(
    tmp_path_factory: pytest.TempPathFactory, table: list[tuple[int, int]], unit: str
) -> None:
    path = tmp_path_factory.mktemp("csv") / "windows.csv"
    text = _seconds if unit == "s" else str
    rows = [f"{text(a)},{text(b)},wood,P1,{i + 1}" for i, (a, b) in enumerate(table)]
    path.write_text("start,stop,object,action,trial\n" + "\n".join(rows) + "\n", "utf-8")
    origin = 1_700_000_000 * NS
    windows = windows_from_csv(path, unit, origin)
    assert [(w.start_ns, w.stop_ns) for w in windows] == [
        (a + origin, b + origin) for a, b in table
    ]
    ordered = sorted(table)
    overlapping = any(b[0] < a[1] for a, b in itertools.pairwise(ordered))
    if overlapping:
        with pytest.raises(BagImportError, match="overlaps"):
            check_no_overlap(windows)
    else:
        assert [w.start_ns for w in check_no_overlap(windows)] == [a + origin for a, _ in ordered]


@SETTINGS
@given(
    period=st.integers(100_000, 50_000_000),
    count=st.integers(1, 600),
    seed=st.integers(0, 2**32 - 1),
    jitter=st.floats(0.0, 0.45),
)
def test_packing_keeps_every_row_within_the_jitter_bound(
    period: int, count: int, seed: int, jitter: float
) -> None:
    rng = np.random.default_rng(seed)
    steps = rng.choice([1, 1, 1, 1, 2, 5], count)  # gaps: a dropped or late sample
    grid = np.cumsum(steps) * period
    noise = rng.integers(-int(0.2 * period), int(0.2 * period) + 1, count)
    stamps = (grid + noise).astype(np.int64)
    rows = Rows(stamps, stamps, rng.normal(size=(count, 2, 3)), 0, 0)
    blocks, deviation, dropped = skin_blocks("force", rows, period, jitter)
    rebuilt = np.concatenate(
        [b.stamp_ns + np.arange(b.data.shape[0], dtype=np.int64) * b.period_ns for b in blocks]
    )
    assert dropped == 0
    assert rebuilt.size == count
    assert bool((np.diff(rebuilt) > 0).all())
    assert int(np.abs(rebuilt - stamps).max()) == deviation <= int(jitter * period)
    np.testing.assert_array_equal(
        np.concatenate([b.data for b in blocks]), rows.data.astype(np.float32)
    )
