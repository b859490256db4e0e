"""The mining reference's tests over time, one object and one frame at a time: runs of an object's
selected frames, how long they last, where they reach one another, and chains of steps
(:mod:`benchmarks.mining_reference`; the definitions are :mod:`scenarios.program`'s)."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

from benchmarks.mining_reference_log import Grid


@dataclass(frozen=True)
class FrameClock:
    """The frames of one log: their times, and how many objects a grid holds.

    Attributes:
        time_s: (F) each frame's time.
        num_objects: the grids' rows.
        interval_s: the median time between frames (the length a run's last frame adds).
    """

    time_s: list[float]
    num_objects: int

    @property
    def num_frames(self) -> int:
        return len(self.time_s)

    @property
    def interval_s(self) -> float:
        intervals = sorted(b - a for a, b in zip(self.time_s, self.time_s[1:]))
        return intervals[len(intervals) // 2] if intervals else 0.0

    def grid(self, value: bool = False) -> Grid:
        return [[value] * self.num_frames for _ in range(self.num_objects)]

    def runs(self, sel: Grid) -> Iterator[tuple[int, int, int]]:
        """(object, first frame, last frame + 1) of each run of ``sel`` (consecutive frames of an object)."""
        for o in range(self.num_objects):
            f = 0
            while f < self.num_frames:
                if not sel[o][f]:
                    f += 1
                    continue
                end = f
                while end < self.num_frames and sel[o][end]:
                    end += 1
                yield o, f, end
                f = end

    def runs_lasting(self, sel: Grid, seconds: float) -> Grid:
        """The runs of ``sel`` that last ``seconds``, from their first frame to their last plus one interval."""
        t, interval_s = self.time_s, self.interval_s
        out = self.grid()
        for o, f, end in self.runs(sel):
            if t[end - 1] - t[f] + interval_s >= seconds - 1e-6:
                for g in range(f, end):
                    out[o][g] = True
        return out

    def runs_holding(self, sel: Grid, marks: Grid) -> Grid:
        """The runs of ``sel`` (consecutive frames of an object) that hold a frame of ``marks``."""
        out = self.grid()
        for o, f, end in self.runs(sel):
            if any(marks[o][g] for g in range(f, end)):
                for g in range(f, end):
                    out[o][g] = True
        return out

    def in_reach(self, frames: list[bool], f: int, step: int, within_s: float) -> bool:
        """Whether one of ``frames`` lies within ``within_s`` of frame ``f``, after it (``step`` 1) or
        before it (−1), not at it."""
        t = self.time_s
        g = f + step
        while 0 <= g < self.num_frames and abs(t[g] - t[f]) <= within_s:
            if frames[g]:
                return True
            g += step
        return False

    def reached(self, steps: list[Grid], gaps_s: list[float]) -> list[Grid]:
        """For each step of a chain, its frames that the steps before it reach in order, each within its
        time of the one before."""
        reached = [steps[0]]
        for step, gap_s in zip(steps[1:], gaps_s, strict=True):
            reached.append([[step[o][f] and self.in_reach(reached[-1][o], f, -1, gap_s)
                             for f in range(self.num_frames)] for o in range(self.num_objects)])
        return reached

    def chained(self, steps: list[Grid], gaps_s: list[float]) -> Grid:
        """The frames of each step that lie on a whole chain: the steps before it reached in order, each
        within its time of the one before, and the steps after it reachable so from it."""
        reached = self.reached(steps, gaps_s)
        kept = reached[-1]
        out = [row[:] for row in kept]
        frames, objects = range(self.num_frames), range(self.num_objects)
        for i in range(len(steps) - 2, -1, -1):
            kept = [[reached[i][o][f] and self.in_reach(kept[o], f, 1, gaps_s[i]) for f in frames] for o in objects]
            out = [[out[o][f] or kept[o][f] for f in frames] for o in objects]
        return out
