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

A frame that arrives more than half a frame period after the fitted line predicts means lost
frames (a frame that is merely late arrives within the jitter): a new run starts there, so a
lost frame stays a gap in the stamps, never a compressed time axis. Memory is bounded: a run's
line is fitted to its latest :data:`FIT_POINTS` messages (the fit follows a slowly wandering
clock), refitted every :data:`REFIT_EVERY` messages and when a window is cut. Runs shorter than
:data:`SLOPE_SPAN_NS` borrow the slope of the last longer run (or the nominal rate): a few
frames cannot measure a period to ppm.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from recorder.errors import BagImportError

if TYPE_CHECKING:
    from fractions import Fraction

    from numpy.typing import NDArray

#: Messages of a run the line is fitted to (the latest ones).
FIT_POINTS = 4096
#: Messages between two fits of the current run's line.
REFIT_EVERY = 64
#: A run must span this long (ns) before its own slope is fitted.
SLOPE_SPAN_NS = 2_000_000_000
#: A run spanning this long (ns) whose slope is off by more than :data:`MAX_DRIFT` is refused.
REFUSE_SPAN_NS = 10_000_000_000
#: Largest relative difference between the sensor's rate and the receive clock (1000 ppm).
MAX_DRIFT = 1e-3
#: Frame periods beyond the fitted line from which a frame counts as lost frames.
GAP_FRAMES = 0.5
_BISECTIONS = 60
_PPM = 1e6
_NS_PER_MS = 1e6


def envelope_slope(n: NDArray[np.float64], r: NDArray[np.float64], lo: float, hi: float) -> float:
    """Return the slope in ``[lo, hi]`` of the lower-envelope line of points ``(n, r)``.

    The line ``r = a + b n`` below every point that is highest at the mean ``n`` (Moon et al.
    1999): ``f(b) = min_i(r_i - b n_i) + b mean(n)`` is concave in ``b`` with subgradient
    ``mean(n) - n_i`` (``i`` the lowest point under slope ``b``), so bisection finds its
    maximum. Written by hand: a 1-D concave maximisation of a few lines, no solver needed.
    """
    mean = float(n.mean())
    for _ in range(_BISECTIONS):
        mid = 0.5 * (lo + hi)
        i = int(np.argmin(r - mid * n))
        if n[i] < mean:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@dataclass(slots=True)
class _Run:
    """Messages without a lost frame between them: stamp - base = a + b * sample index."""

    base: int
    b: float
    a: float = 0.0
    ns: deque[int] = field(default_factory=lambda: deque(maxlen=FIT_POINTS))
    rs: deque[int] = field(default_factory=lambda: deque(maxlen=FIT_POINTS))
    next_first: int = 0
    fresh: int = 0


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
    run_of: list[int] = field(default_factory=list)
    first_of: list[int] = field(default_factory=list)
    runs: int = 0
    lost_frames: int = 0
    current: _Run | None = None
    closed: dict[int, tuple[int, float, float]] = field(default_factory=dict)
    slope: float | None = None
    best: tuple[float, float] = (0.0, 0.0)
    residuals: list[float] = field(default_factory=lambda: [0, 0.0, 0.0, 0.0])

    def push(self, stamp: int) -> None:
        """Place a message (its stamp) on a run: the current one, or a new one after a gap."""
        run = self.current
        if run is not None:
            n = run.next_first + self.stamped
            excess = (stamp - run.base) - (run.a + run.b * n)
            frame = self.count * run.b
            if excess > GAP_FRAMES * frame:
                self.lost_frames += max(1, round(excess / frame))
                self._close(run)
                run = None
        if run is None:
            b = self.slope if self.slope is not None else float(self.period)
            run = _Run(stamp, b, a=-b * self.stamped)
            self.current = run
            self.runs += 1
        n, r = run.next_first + self.stamped, stamp - run.base
        run.ns.append(n)
        run.rs.append(r)
        run.a = min(run.a, r - run.b * n)  # the envelope only moves down between fits
        self.run_of.append(self.runs - 1)
        self.first_of.append(run.next_first)
        run.next_first += self.count
        run.fresh += 1
        if run.fresh >= REFIT_EVERY:
            self._fit(run)

    def _close(self, run: _Run) -> None:
        """Fit a run a last time and keep its line for its messages still buffered."""
        self._fit(run)
        self.closed[self.runs - 1] = (run.base, run.a, run.b)

    def _fit(self, run: _Run) -> None:
        """Fit the run's line to its latest messages; count the new messages' residuals.

        Raises:
            BagImportError: A long run's stamps advance at a rate far from ``rate_hz``.
        """
        n = np.fromiter(run.ns, dtype=np.float64, count=len(run.ns))
        r = np.fromiter(run.rs, dtype=np.float64, count=len(run.rs))
        nominal = float(self.period)
        span = (n[-1] - n[0]) * nominal
        if span >= SLOPE_SPAN_NS:
            b = envelope_slope(n, r, 0.9 * nominal, 1.1 * nominal)
            drift = b / nominal - 1
            if abs(drift) > MAX_DRIFT:
                if span >= REFUSE_SPAN_NS:
                    msg = (
                        f"{self.where}: the message stamps advance {drift * _PPM:+.0f} ppm off "
                        f"rate_hz = {1e9 / nominal:g} (they say {1e9 / b:.6g} Hz); fix rate_hz "
                        "or samples_per_message"
                    )
                    raise BagImportError(msg)
                b = nominal * (1 + np.clip(drift, -MAX_DRIFT, MAX_DRIFT))
            self.slope = b
            if span >= self.best[0]:
                self.best = (span, drift)
        else:
            b = self.slope if self.slope is not None else nominal
        run.b = b
        run.a = float((r - b * n).min())
        if run.fresh:
            fresh = r[-run.fresh :] - (run.a + b * n[-run.fresh :])
            stats = self.residuals
            stats[0] += fresh.size
            stats[1] += float(fresh.sum())
            stats[2] += float((fresh * fresh).sum())
            stats[3] = max(stats[3], float(fresh.max()))
            run.fresh = 0

    def stamps(self, first: int, last: int) -> NDArray[np.int64]:
        """Return the sample stamps of buffered messages ``first:last``, message-major."""
        if self.current is not None and self.current.fresh:
            self._fit(self.current)
        runs = np.asarray(self.run_of[first:last], dtype=np.int64)
        firsts = np.asarray(self.first_of[first:last], dtype=np.int64)
        index = firsts[:, None] + np.arange(self.count, dtype=np.int64)[None, :]
        out = np.empty(index.shape, dtype=np.int64)
        for run in np.unique(runs).tolist():
            base, a, b = self._line(int(run))
            mine = runs == run
            out[mine] = base + np.floor(a + b * index[mine]).astype(np.int64)
        return out.reshape(-1)

    def _line(self, run: int) -> tuple[int, float, float]:
        """Return ``(base, a, b)`` of a run."""
        if run == self.runs - 1 and self.current is not None:
            return self.current.base, self.current.a, self.current.b
        return self.closed[run]

    def cut(self, index: int) -> None:
        """Forget the first ``index`` messages (and the lines of runs none of them is on)."""
        del self.run_of[:index]
        del self.first_of[:index]
        oldest = self.run_of[0] if self.run_of else self.runs - 1
        for run in [r for r in self.closed if r < oldest]:
            del self.closed[run]

    def summary(self) -> dict[str, Any]:
        """Return runs, gaps, lost frames, jitter (ms) and drift (ppm) for the import report.

        The jitter is how far message stamps lie above the fitted line (their latency beyond
        the fastest frame's): the largest and the standard deviation. The drift is of the
        longest fit: the sensor's period on the receive clock relative to ``rate_hz``.
        """
        if self.current is not None and self.current.fresh:
            self._fit(self.current)
        count, total, squares, largest = self.residuals
        mean = total / count if count else 0.0
        sd = float(np.sqrt(max(squares / count - mean * mean, 0.0))) if count else 0.0
        return {
            "runs": self.runs,
            "gaps": max(self.runs - 1, 0),
            "lost_frames": self.lost_frames,
            "jitter_max_ms": largest / _NS_PER_MS,
            "jitter_sd_ms": sd / _NS_PER_MS,
            "drift_ppm": self.best[1] * _PPM if self.best[0] else None,
            "fitted_span_s": self.best[0] / 1e9,
        }
