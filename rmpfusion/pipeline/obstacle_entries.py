"""Recordings that pass through an obstacle of the run's world, found before anything learns from them.

A recording comes from the user's world; the run's scene is the experiment's (``experiment=recorded_arm`` places
the Franka experiment's cylinder). A demonstration that passes through one of its obstacles teaches the tree to go
through it, against its own barriers, and nothing in the losses says so. Every demonstration on the step grid (what
training reads) is measured by the environment (``LearnsFromRecordings.recorded_depths``): an arm's spheres, which
contain its links' meshes, against the scene's distance maps, as the batched collision check measures rollouts, with
the simulator's closest-point query confirming the configurations the spheres find inside; the plane's position
against the discs its recordings' aux columns place. Each stretch of samples inside is one entry: which recording,
from when to when (s after the demonstration's start and on the file's own clock), which point, which obstacle,
how deep. What the run then does is ``data.obstacle_entries``: ``refuse`` (the default: validation and the collect
stage stop with one message naming every entry and the fix), ``warn`` (learn from them, saying so), or ``drop`` (the
entering recordings are left out before the split). Entries the spheres find and the simulator does not confirm
(the link's mesh stays clear inside its sphere) are reported, never refused.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from ..envs.protocol import JointSpace, LearnsFromRecordings, ObstacleDepths
from ..recordings.recording import RecordingError
from ..recordings.signals import States, runs

#: at most this many entries are named in one message (metrics.json keeps them all)
NAMED = 5
#: stretches inside less than this apart (s) are one entry: a recording skimming an obstacle's surface dips in and
#: out with its noise
MERGE_GAP = 0.25


class ObstacleEntryError(RecordingError):
    """Recordings that enter an obstacle of the run's world, refused before training (``data.obstacle_entries``)."""


@dataclass(frozen=True)
class ObstacleEntry:
    """One stretch of a recording inside an obstacle: times in s after the demonstration's start (its rest trimmed)
    and, for the deepest sample, on the file's clock; ``depth``: how far (m) the point is inside by the measure;
    ``confirmed``: the simulator finds the body inside too (always, where the measure is the body itself), and
    ``body_depth`` (m) how deep it finds it (None where it finds the body clear, or where the measure is exact)."""

    recording: str
    start: float
    end: float
    deepest: float
    file_time: float
    point: str
    obstacle: str
    depth: float
    confirmed: bool
    body_depth: float | None

    def line(self) -> str:
        """The entry as the message and the run's log say it."""
        body = (
            f"; the links' meshes {self.body_depth:.3f} m deep by the simulator"
            if self.body_depth is not None
            else ""
            if self.confirmed
            else "; the simulator finds the links' meshes clear there (the sphere alone enters)"
        )
        return (
            f"{self.recording}: from {self.start:.2f} to {self.end:.2f} s, deepest at {self.deepest:.2f} s (file time "
            f"{self.file_time:.3f} s): {self.point} {self.depth:.3f} m inside {self.obstacle}{body}"
        )

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass(frozen=True)
class EntriesFound:
    """Every entry of every recording checked, and what the depths measure."""

    entries: list[ObstacleEntry]
    recordings: int
    measure: str

    @property
    def entering(self) -> list[str]:
        """The recordings with a confirmed entry, in order: those ``data.obstacle_entries`` refuses or drops."""
        return list(dict.fromkeys(e.recording for e in self.entries if e.confirmed))

    @property
    def confirmed(self) -> list[ObstacleEntry]:
        return [e for e in self.entries if e.confirmed]

    @property
    def possible(self) -> list[ObstacleEntry]:
        """The entries the spheres find and the simulator does not confirm."""
        return [e for e in self.entries if not e.confirmed]

    def as_dict(self, policy: str, dropped: Sequence[str] = ()) -> dict:
        """What metrics.json records in its data section."""
        return {
            "checked": self.recordings,
            "measure": self.measure,
            "policy": policy,
            "entering": self.entering,
            "dropped": list(dropped),
            "entries": [e.as_dict() for e in self.entries],
        }


def _world_rows(env: LearnsFromRecordings, states: Sequence[States]) -> dict[str, torch.Tensor]:
    """Each demonstration's aux state as the dataset gives it (the environment's for its goal, its own entries from
    its file over those), one row per grid sample of every demonstration in order."""
    goals = torch.as_tensor(np.stack([s.goal for s in states]), dtype=torch.float64)
    per_demo = env.recorded_aux(goals)
    counts = torch.tensor([len(s.t) for s in states])
    rows = {}
    names = set(per_demo) | {k for s in states for k in s.aux}
    for name in names:
        values = [
            torch.as_tensor(np.asarray(s.aux[name], np.float64)).reshape(-1)
            if name in s.aux
            else per_demo[name][n].to(torch.float64).reshape(-1)
            for n, s in enumerate(states)
        ]
        rows[name] = torch.stack(values).repeat_interleave(counts, 0)
    return rows


def _merged(stretches: list[tuple[int, int]], t: np.ndarray) -> list[tuple[int, int]]:
    """``stretches`` (first, last sample) with those less than ``MERGE_GAP`` apart joined."""
    out: list[tuple[int, int]] = []
    for a, b in stretches:
        if out and t[a] - t[out[-1][1]] < MERGE_GAP:
            out[-1] = (out[-1][0], b)
        else:
            out.append((a, b))
    return out


def _entries_of(state: States, depths: ObstacleDepths, at: slice) -> list[ObstacleEntry]:
    """The entries of one demonstration, whose samples are ``at`` in ``depths``."""
    clearance = depths.clearance[at].numpy()
    out = []
    for a, b in _merged(runs(clearance < 0), state.t):
        k = a + int(np.argmin(clearance[a : b + 1]))
        body = None if depths.confirmed is None else depths.confirmed[at].numpy()[a : b + 1]
        confirmed = body is None or bool(np.nanmin(body) <= 0)
        out.append(
            ObstacleEntry(
                recording=state.source,
                start=float(state.t[a]),
                end=float(state.t[b]),
                deepest=float(state.t[k]),
                file_time=state.start_time + float(state.t[k]),
                point=depths.points[int(depths.point[at][k])],
                obstacle=depths.obstacles[int(depths.obstacle[at][k])],
                depth=float(-clearance[k]),
                confirmed=confirmed,
                body_depth=float(-np.nanmin(body)) if body is not None and confirmed else None,
            )
        )
    return out


def find_entries(env: LearnsFromRecordings, states: Sequence[States]) -> EntriesFound:
    """Every entry of the demonstrations ``states`` (on the step grid) into the obstacles of their worlds."""
    q = torch.as_tensor(np.concatenate([s.q for s in states]), dtype=torch.float64)
    depths = env.recorded_depths(q, _world_rows(env, states))
    entries, at = [], 0
    for s in states:
        entries += _entries_of(s, depths, slice(at, at + len(s.t)))
        at += len(s.t)
    return EntriesFound(entries, len(states), depths.measure)


def world_fix(env: LearnsFromRecordings) -> str:
    """How a user states the world the recordings were made in, in one line."""
    if isinstance(env, JointSpace):
        return (
            "if your world is not the run's scene, state it in one line: env.scene.obstacles=[] (no obstacles) or "
            "scene=<your scene file> (docs/guides/scenes.md)"
        )
    return "if your world has no such disc, fix the aux columns that place it (data.aux_columns)"


def entries_message(env: LearnsFromRecordings, found: EntriesFound) -> str:
    """The refusal: every confirmed entry (the first ``NAMED``), what was measured, and the fixes."""
    confirmed, entering = found.confirmed, len(found.entering)
    named = "; ".join(e.line() for e in confirmed[:NAMED])
    more = f"; and {len(confirmed) - NAMED} more" if len(confirmed) > NAMED else ""
    return (
        f"{entering} of {found.recordings} recordings {'enters' if entering == 1 else 'enter'} an obstacle of the "
        f"run's world ({len(confirmed)} {'entry' if len(confirmed) == 1 else 'entries'}; measured by "
        f"{found.measure}): {named}{more}. Learning from them would teach the "
        f"tree to pass through the obstacle. {world_fix(env).capitalize()}; or leave those recordings out "
        "(data.obstacle_entries=drop), or learn from them anyway (data.obstacle_entries=warn)"
    )


def summary_line(found: EntriesFound, policy: str) -> str:
    """What the check found, in one line (``rmpfusion-validate``'s summary)."""
    n, entering, possible = found.recordings, found.entering, found.possible
    if entering:
        done = {"warn": "learned from (data.obstacle_entries=warn)", "drop": "left out (data.obstacle_entries=drop)"}
        head = f"{len(entering)} of {n} recordings enter an obstacle of the run's world, {done.get(policy, 'refused')}"
    else:
        head = f"none of the {n} recordings enters an obstacle of the run's world"
    if possible:
        deepest = max(possible, key=lambda e: e.depth)
        head += (
            f"; the robot's spheres alone enter in {len({e.recording for e in possible})} (the deepest "
            f"{deepest.depth:.3f} m, {deepest.point} in {deepest.obstacle}; the links' meshes clear by the "
            "simulator: not refused)"
        )
    return head


def possible_line(found: EntriesFound) -> str:
    """One line for the entries the spheres find and the simulator does not confirm: not refused, but the tree's
    barriers act on those spheres and push against the demonstrations there."""
    possible = found.possible
    deepest = max(possible, key=lambda e: e.depth)
    recordings = len({e.recording for e in possible})
    return (
        f"the robot's spheres enter an obstacle in {recordings} of {found.recordings} recordings ({len(possible)} "
        f"stretches, the deepest {deepest.line()}), while the simulator finds the links' meshes clear: not refused, "
        "but the tree's barriers act on those spheres and push against these demonstrations there (every stretch: "
        "metrics.json, data.recordings.obstacle_entries)"
    )


def apply_policy(
    env: LearnsFromRecordings, states: list[States], policy: str
) -> tuple[list[States], EntriesFound, list[str]]:
    """The demonstrations to learn from under ``data.obstacle_entries`` (``policy``), what was found, and the
    warnings to say: ``refuse`` raises ``ObstacleEntryError`` on any confirmed entry, ``drop`` leaves the entering
    recordings out, ``warn`` keeps them; entries the simulator does not confirm are said, never refused."""
    found = find_entries(env, states)
    warnings = [possible_line(found)] if found.possible else []
    if not found.entering:
        return states, found, warnings
    if policy == "refuse":
        raise ObstacleEntryError(entries_message(env, found))
    if policy == "drop":
        gone = set(found.entering)
        warnings.append(
            f"left out {len(gone)} of {len(states)} recordings that enter an obstacle (data.obstacle_entries=drop): "
            + "; ".join(e.line() for e in found.confirmed)
        )
        return [s for s in states if s.source not in gone], found, warnings
    warnings.append(
        f"learning from {len(found.entering)} recordings that enter an obstacle (data.obstacle_entries=warn): "
        + "; ".join(e.line() for e in found.confirmed)
    )
    return states, found, warnings
