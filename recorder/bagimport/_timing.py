"""Sample stamps of receive-stamped messages: from the sensor's rate, anchored on the stamps.

Many drivers stamp a frame when it arrives (the receive time), not when its samples were
measured: the stamps of a sensor that sends 22 samples every 10 ms vary by a few ms from frame
to frame (scheduling, USB polling). Stamping the samples of each frame from its own stamp would
put samples of consecutive frames on top of each other. With ``timing = "rate"`` a modality's
samples are stamped from the sensor's own rate instead: the messages form *runs* (no frame
lost), and sample ``k`` of a run lies at ``anchor + k * period``. The line ``(anchor, period)``
is fitted to the message stamps as their lower envelope (the minimum-latency line: no frame
arrives before its samples exist, the fastest frames show the sensor's clock), the linear
programme of Moon, Skelly and Towsley, "Estimation and removal of clock skew from network
delay measurements" (INFOCOM 1999): maximise the line at the mean sample index subject to
the line lying below every stamp. Its slope is the period on the receive clock, so the drift
between the sensor's crystal and the receive clock is measured (ppm), not assumed away.

A frame that arrives more than half a frame period after the fitted line predicts means a gap
(a frame that is merely late arrives within the jitter): a new run starts there, so a gap
stays a gap in the stamps, never a compressed time axis. Without a counter a gap cannot tell
lost frames from a pause of the driver (the time between two recordings of a session): it is
reported as a gap with its length, and no frame is counted lost. With a frame counter
(``counter``) the run goes on across lost frames, their samples skipped exactly and counted
as lost frames (loss within a run), and a late frame is only late; a counter that goes back
(or that the stamps contradict by more than half its ``counter_modulo``) starts a new run,
and the frames between the runs are not counted as lost. Memory is bounded: the
lines are fitted to the latest :data:`FIT_POINTS` messages (the fit follows a slowly wandering
clock), refitted every :data:`REFIT_EVERY` messages and when a window is cut. Until those
messages span :data:`SLOPE_SPAN_NS` the period is the last one fitted (or the nominal rate):
a few frames cannot measure a period to ppm.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from recorder.errors import BagImportError
from recorder.live import counter_skipped

if TYPE_CHECKING:
    from collections.abc import Sequence
    from fractions import Fraction

    from numpy.typing import NDArray

#: Messages of a run the line is fitted to (the latest ones).
FIT_POINTS = 4096
#: Messages between two fits of the lines.
REFIT_EVERY = 256
#: A run must span this long (ns) before its own slope is fitted.
SLOPE_SPAN_NS = 2_000_000_000
#: A run spanning this long (ns) whose slope is off by more than :data:`MAX_DRIFT` is refused.
REFUSE_SPAN_NS = 10_000_000_000
#: Largest relative difference between the sensor's rate and the receive clock (1000 ppm).
MAX_DRIFT = 1e-3
#: Frame periods beyond the fitted line from which a frame counts as lost frames.
GAP_FRAMES = 0.5
_GOLDEN = (5**0.5 - 1) / 2
#: Relative precision of a fitted period.
_PRECISION = 1e-12
#: Half-width of the bracket around the previous period (100 ppm), and its edge zone.
_BRACKET = 1e-4
_EDGE = 0.01
_PPM = 1e6
_NS_PER_MS = 1e6


def envelope_slope(
    runs: Sequence[tuple[NDArray[np.float64], NDArray[np.float64]]],
    lo: float,
    hi: float,
    guess: float | None = None,
) -> float:
    """Return the common slope in ``[lo, hi]`` of the lower-envelope lines of runs of points.

    Each run ``(n, r)`` gets the line ``r = a_k + b n`` below its points; the slope ``b``
    maximises ``f(b) = sum_k size_k (min_i(r_i - b n_i) + b mean_k(n))`` (Moon et al. 1999,
    one anchor per run), a concave function of ``b``: a golden-section search finds its
    maximum, to 1e-12 of ``b``, first near ``guess`` (the previous fit), then, if the maximum
    is at that bracket's edge, over ``[lo, hi]``. Written by hand: a 1-D concave maximisation
    of a few lines, no solver needed.
    """

    def f(b: float) -> float:
        return sum(r.size * (float((r - b * n).min()) + b * float(n.mean())) for n, r in runs)

    def search(lo: float, hi: float) -> float:
        while hi - lo > _PRECISION * hi:
            left, right = hi - _GOLDEN * (hi - lo), lo + _GOLDEN * (hi - lo)
            if f(left) < f(right):
                lo = left
            else:
                hi = right
        return 0.5 * (lo + hi)

    if guess is not None:
        near = (max(lo, guess * (1 - _BRACKET)), min(hi, guess * (1 + _BRACKET)))
        found = search(*near)
        if near[0] + _EDGE * (near[1] - near[0]) < found < near[1] - _EDGE * (near[1] - near[0]):
            return found
    return search(lo, hi)


@dataclass(slots=True)
class Timeline:
    """Per-sample stamps of one modality of receive-stamped messages (``timing = "rate"``).

    Attributes:
        where: ``topic [skin.<modality>]``, for messages.
        period: The nominal sample period (from ``rate_hz``), ns.
        count: Samples per message.
        stamped: The sample of a message its stamp belongs to (0: first, count - 1: last).
    """

    where: str
    period: Fraction
    count: int
    stamped: int
    #: The frame counter's modulo (0: it does not wrap).
    modulo: int = 0
    counter: int | None = None
    #: Per buffered message: its run and the index of its first sample in the run.
    run_of: list[int] = field(default_factory=list)
    first_of: list[int] = field(default_factory=list)
    #: The latest messages: (run, stamped sample index, stamp - the run's base).
    points: deque[tuple[int, int, int]] = field(default_factory=lambda: deque(maxlen=FIT_POINTS))
    #: Per run: (base stamp, a, b): sample k at base + a + b * k.
    lines: dict[int, tuple[int, float, float]] = field(default_factory=dict)
    runs: int = 0
    next_first: int = 0
    lost_frames: int = 0
    gap_ns: int = 0
    fresh: int = 0
    slope: float | None = None
    best: tuple[float, float] = (0.0, 0.0)
    residuals: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0, 0.0])

    def push(self, stamp: int, counter: int | None = None) -> None:
        """Place a message on a run: the current one, or a new one after a gap.

        Args:
            stamp: The message's stamp.
            counter: Its frame counter (a field the map names), or None: lost frames are
                then seen in the stamps only.
        """
        run = self.runs - 1
        if run >= 0:
            skipped = self._skipped(counter)
            base, a, b = self.lines[run]
            frame = self.count * b
            n = self.next_first + skipped * self.count + self.stamped
            excess = (stamp - base) - (a + b * n)
            # without a counter a frame more than half a frame late means lost frames; with
            # one, a late frame is only late unless it is so late that the counter may have
            # wrapped, and a counter the stamps contradict (a reset) starts a new run
            if counter is None:
                late = excess > GAP_FRAMES * frame
            else:
                late = bool(self.modulo) and excess > self.modulo / 2 * frame
            early = counter is not None and excess < -GAP_FRAMES * frame
            if skipped < 0 or late or early:
                self.gap_ns += max(round(excess), 0)  # between runs: a gap, not loss
                run = -1
            else:
                self.next_first += skipped * self.count
                self.lost_frames += skipped
        self.counter = counter
        if run < 0:
            b = self.slope if self.slope is not None else float(self.period)
            run, self.next_first = self.runs, 0
            self.lines[run] = (stamp, -b * self.stamped, b)
            self.runs += 1
        base, a, b = self.lines[run]
        n, r = self.next_first + self.stamped, stamp - base
        self.points.append((run, n, r))
        self.lines[run] = (base, min(a, r - b * n), b)  # the envelope only moves down
        self.run_of.append(run)
        self.first_of.append(self.next_first)
        self.next_first += self.count
        self.fresh += 1
        if self.fresh >= REFIT_EVERY:
            self._fit()

    def _skipped(self, counter: int | None) -> int:
        """Return the frames lost before a message by its counter (-1: the counter went back)."""
        if counter is None or self.counter is None:
            return 0
        step = counter - self.counter
        if self.modulo:
            step %= self.modulo
        return step - 1 if step > 0 else -1

    def _fit(self) -> None:
        """Fit the lines to the latest messages; count the new messages' residuals.

        Raises:
            BagImportError: The stamps advance at a rate far from ``rate_hz``.
        """
        table = np.asarray(self.points, dtype=np.float64).reshape(-1, 3)
        bounds = np.flatnonzero(np.diff(table[:, 0])) + 1
        runs = [(c[:, 1], c[:, 2]) for c in np.split(table, bounds)]
        nominal = float(self.period)
        span = sum(float(n[-1] - n[0]) for n, _ in runs) * nominal
        b = self.slope if self.slope is not None else nominal
        if span >= SLOPE_SPAN_NS:
            b = envelope_slope(runs, 0.9 * nominal, 1.1 * nominal, self.slope)
            drift = b / nominal - 1
            if abs(drift) > MAX_DRIFT:
                if span >= REFUSE_SPAN_NS:
                    msg = (
                        f"{self.where}: the period the message stamps show is "
                        f"{drift * _PPM:+.0f} ppm off rate_hz = {1e9 / nominal:g} (they say "
                        f"{1e9 / b:.6g} Hz); fix rate_hz or samples_per_message"
                    )
                    raise BagImportError(msg)
                b = nominal * (1 + float(np.clip(drift, -MAX_DRIFT, MAX_DRIFT)))
            self.slope = b
            if span >= self.best[0]:
                self.best = (span, b / nominal - 1)
        anchors = np.empty(table.shape[0])
        for (n, r), run, at in zip(runs, table[np.r_[0, bounds], 0], np.r_[0, bounds], strict=True):
            a = float((r - b * n).min())
            self.lines[int(run)] = (self.lines[int(run)][0], a, b)
            anchors[at : at + n.size] = a
        if self.fresh:
            tail = table[-self.fresh :]
            fresh = tail[:, 2] - (anchors[-self.fresh :] + b * tail[:, 1])
            stats = self.residuals
            stats[0] += fresh.size
            stats[1] += float(fresh.sum())
            stats[2] += float((fresh * fresh).sum())
            stats[3] = max(stats[3], float(fresh.max()))
            self.fresh = 0

    def stamps(self, first: int, last: int) -> NDArray[np.int64]:
        """Return the sample stamps of buffered messages ``first:last``, message-major."""
        if self.fresh:
            self._fit()
        runs = np.asarray(self.run_of[first:last], dtype=np.int64)
        firsts = np.asarray(self.first_of[first:last], dtype=np.int64)
        index = firsts[:, None] + np.arange(self.count, dtype=np.int64)[None, :]
        out = np.empty(index.shape, dtype=np.int64)
        for run in np.unique(runs).tolist():
            base, a, b = self.lines[int(run)]
            mine = runs == run
            out[mine] = base + np.floor(a + b * index[mine]).astype(np.int64)
        return out.reshape(-1)

    def cut(self, index: int) -> None:
        """Forget the first ``index`` messages (and the lines of runs nothing refers to)."""
        del self.run_of[:index]
        del self.first_of[:index]
        oldest = min(
            self.run_of[0] if self.run_of else self.runs - 1,
            self.points[0][0] if self.points else self.runs - 1,
            self.runs - 1,
        )
        for run in [r for r in self.lines if r < oldest]:
            del self.lines[run]

    def summary(self) -> dict[str, Any]:
        """Return runs, gaps, lost frames, jitter (ms) and drift (ppm) for the import report.

        Lost frames are those a frame counter shows missing inside a run; the gaps between
        runs are reported as ``gaps`` and their length beyond the fitted line (``gap_s``).

        The jitter is how far message stamps lie above the fitted lines (their latency beyond
        the fastest frame's): the largest and the standard deviation. The drift is of the
        fit over the longest span: the sensor's period on the receive clock against
        ``rate_hz`` (positive: its samples are further apart than ``rate_hz`` says).
        """
        if self.fresh:
            self._fit()
        count, total, squares, largest = self.residuals
        mean = total / count if count else 0.0
        sd = float(np.sqrt(max(squares / count - mean * mean, 0.0))) if count else 0.0
        return {
            "runs": self.runs,
            "gaps": max(self.runs - 1, 0),
            "lost_frames": self.lost_frames,
            "gap_s": self.gap_ns / 1e9,
            "jitter_max_ms": largest / _NS_PER_MS,
            "jitter_sd_ms": sd / _NS_PER_MS,
            "drift_ppm": self.best[1] * _PPM if self.best[0] else None,
            "fitted_span_s": self.best[0] / 1e9,
        }


@dataclass(slots=True)
class MessageCount:
    """The messages of a topic stamped by their own stamps whose counter the map names.

    ``timing = "message"`` with ``counter``: each message's counter is compared with the
    previous one's; the numbers it skipped are lost messages. A counter that repeats is a
    duplicate; one that goes back, or whose advance the stamps contradict (as the live
    accounting judges it, :func:`recorder.live.counter_skipped`), is a reset: nothing is
    counted lost there.
    """

    #: The counter wraps at this value (0: it does not wrap).
    modulo: int = 0
    #: The nominal message period, ns (0: unknown: the stamps do not check the counter).
    period_ns: int = 0
    messages: int = 0
    lost: int = 0
    duplicated: int = 0
    resets: int = 0
    last: tuple[int, int] | None = None

    def push(self, stamp: int, counter: int) -> None:
        """Count one message (its stamp, ns, and its counter)."""
        self.messages += 1
        last, self.last = self.last, (counter, stamp)
        if last is None:
            return
        skipped = counter_skipped(last, self.last, modulo=self.modulo, period_ns=self.period_ns)
        if skipped is None:
            self.resets += 1
        elif skipped < 0:
            self.duplicated += 1
            self.last = last
        else:
            self.lost += skipped

    def summary(self) -> dict[str, int]:
        """Return messages, lost, duplicated and resets for the import report."""
        return {
            "messages": self.messages,
            "lost": self.lost,
            "duplicated": self.duplicated,
            "resets": self.resets,
        }
