"""The phases of a hand-rotation (Ferraris) session: six static faces and a full turn about
each sensor axis, found in the data or taken from a person's annotation.

From the data: the unit is still where the gyro stays within a few noise levels of its
resting output for a while (blocks of ``block_s``); a still stretch of at least
``min_still_s`` is a *rest*, and its face is the axis the accelerometer finds gravity on.
Between rests the unit moves. A *turn* is a chain of moves between rests on the same face
whose rotation lies along that face's axis (a turn done in steps rests in between); its
angle, integrated from the gyro, must come within ``angle_tolerance`` of a whole number of
full turns, which then is the reference. Each face's longest rest is its observation. A
recording cut to its sections (no move between one and the next) is first split where
gravity jumps further than the gyro saw the unit turn (:func:`find_cuts`); a piece's still
edge then anchors a turn as a rest does.

From a ``section`` column (``x_p`` ... ``z_a``, ``x_rot`` ... ``z_rot``: the contract's
extension, docs/log-format.md) the labelled samples are the observations; the data only
give each turn's direction.

Each observation becomes a hold of the common schema (:mod:`gyrocal.io.holds`): a face is a
hold at rate 0 with the up axis as its mount; a turn is a hold whose reference rate is its
known angle over its duration, so that its time-weighted mean output obeys the model of the
mean rate exactly, ``mean(w) = K θ n / T + B`` (what the 12-parameter model fits). A turn's
spread (``std_*``) carries the uncertainty of the hand's angle, so every fit and floor that
reads it weighs the turn by what it can tell.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np
import pandas as pd

from ...io.errors import SegmentationError
from ...io.holds import Segmentation, hold_table, no_stable_periods, segments_of_holds, timeline, true_runs
from ...io.log import ACCEL, FACES, GYRO, SECTIONS, TURNS, RigLog, declared_units, open_dataset, time_seconds
from ...terms import AXES
from ..registry import checked_options

FULL_TURN = 360.0


def face_mount(label: str) -> str:
    """``x_p`` → ``+x`` (x up), ``x_a`` → ``-x``."""
    return ("+" if label[2] == "p" else "-") + label[0]


def read_sections(log: RigLog, t: np.ndarray) -> np.ndarray | None:
    """The ``section`` label of every kept row (None when the log has no such column):
    read beside the numeric columns and matched on ``t`` (seconds as the read gives them,
    strictly increasing), since rows with a non-finite value were dropped from those."""
    dataset = open_dataset(Path(log.path))
    if "section" not in dataset.schema.names:
        return None
    table = dataset.to_table(columns=["t", "section"])
    labels = table.column("section").to_pandas().astype(object).to_numpy()
    t_all = time_seconds(
        table.column("t").combine_chunks(), Path(log.path), [], declared_units(dataset.schema, Path(log.path))
    )
    if len(t_all) != len(t):
        rows = np.searchsorted(t_all, t)
        labels = labels[np.clip(rows, 0, len(labels) - 1)]
    labels = np.where(pd.isna(labels), "", labels).astype(str)
    unknown = sorted(set(np.unique(labels)) - set(SECTIONS) - {""})
    if unknown:
        raise SegmentationError(
            f"column section holds {', '.join(map(repr, unknown[:5]))}; "
            f"expected {' '.join(SECTIONS)} or empty",
            source=log.path,
        )
    return labels


def _face_of(accel_mean: np.ndarray, share: float) -> str | None:
    """The face a rest lies on: the axis that takes ``share`` of gravity (in g: 0.6–1.4)."""
    norm = float(np.linalg.norm(accel_mean))
    if not 0.6 <= norm <= 1.4:
        return None
    k = int(np.argmax(np.abs(accel_mean)))
    if abs(accel_mean[k]) < share * norm:
        return None
    return ("+" if accel_mean[k] > 0 else "-") + AXES[k]


def white_noise(gyro: np.ndarray) -> np.ndarray:
    """Per-axis white noise (deg/s per sample) from successive differences, robustly (the
    median absolute difference ignores the motion)."""
    d = np.diff(gyro, axis=0)
    return np.median(np.abs(d - np.median(d, axis=0)), axis=0) / 0.6745 / np.sqrt(2.0)


# A cut recording: gravity's direction is compared over this much time on either side of a
# sample boundary, and a piece's edge may end a turn when the unit is still within as long
# of it: the section was cut as the motion began or ended, not in its middle (a cut in a
# pause between strokes leaves a part of a turn, which its angle refuses).
CUT_WINDOW_S = 0.05


def edge_samples(dt: float) -> int:
    return max(2, int(round(CUT_WINDOW_S / dt))) if dt > 0 else 2


def find_cuts(
    t: np.ndarray, gyro: np.ndarray, accel: np.ndarray, opts: dict, *, dt: float, spans: np.ndarray
) -> np.ndarray:
    """The rows where a recording cut to its sections jumps from one section to the next:
    sample indices ``k`` (a piece starts at ``k``), in order.

    A cut is where gravity's direction, averaged over ``CUT_WINDOW_S`` on either side, turns
    by more than ``cut_angle_deg`` beyond what the gyro saw the unit turn over the same
    samples (a rotation of the body turns gravity in its frame by as much, a hand's push
    by a few tens of degrees at most), or where time jumps by more than ``cut_gap_s``. Both
    sides must read about 1 g: an impact or a throw is no cut."""
    n = len(t)
    cuts = [np.flatnonzero(np.diff(t) > opts["cut_gap_s"]) + 1] if n > 1 else []
    w = edge_samples(dt)
    if n >= 2 * w:
        # a missing accelerometer value shortens its window's vector: no cut is found there
        ca = np.vstack([np.zeros(3), np.cumsum(np.where(np.isfinite(accel), accel, 0.0), axis=0)])
        k = np.arange(w, n - w + 1)
        before, after = (ca[k] - ca[k - w]) / w, (ca[k + w] - ca[k]) / w
        nb, na = np.linalg.norm(before, axis=1), np.linalg.norm(after, axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            cos = np.einsum("ij,ij->i", before, after) / (nb * na)
        turned_by_gravity = np.degrees(np.arccos(np.clip(np.nan_to_num(cos, nan=1.0), -1.0, 1.0)))
        # the gyro's rotation over the same samples (an upper bound: the bias is in it)
        rate = np.linalg.norm(gyro - np.median(gyro, axis=0), axis=1) * spans
        cr = np.r_[0.0, np.cumsum(rate)]
        unexplained = turned_by_gravity - (cr[k + w] - cr[k - w])
        about_1g = (np.abs(nb - 1.0) < 0.4) & (np.abs(na - 1.0) < 0.4)
        lo, hi = true_runs((unexplained > opts["cut_angle_deg"]) & about_1g)
        # one cut per run of flagged boundaries: where the jump is largest
        cuts.append(
            np.array(
                [k[a + int(np.argmax(unexplained[a:b]))] for a, b in zip(lo, hi, strict=False)],
                dtype=np.int64,
            )
        )
    rows = np.unique(np.concatenate(cuts)) if cuts else np.zeros(0, np.int64)
    return rows[(rows > 0) & (rows < n)]


class Phase(NamedTuple):
    """A face or a turn: its label (``x_p`` … ``z_rot``) and its rows ``first:end``."""

    label: str
    first: int
    end: int


class FoundPhases(NamedTuple):
    phases: list[Phase]
    warnings: list[str]
    largest: dict[str, float]  # per axis, the largest rotation not taken for a turn (deg)
    cuts: int  # where a recording cut to its sections was split


class Stillness(NamedTuple):
    """Where the unit rests: the rests (first row, end row) and the face each lies on."""

    rests: list[tuple[int, int]]
    faces: list[str | None]
    cuts: np.ndarray  # the rows where a recording cut to its sections was split
    rest_level: np.ndarray  # the gyro's resting output
    limit: float  # deg/s: the least deviation from it that is motion
    block: int  # samples in a block
    edge: int  # samples left off both ends of a rest


class Anchor(NamedTuple):
    """What a turn runs between: a rest, or the still edge of a piece of a cut recording."""

    first: int
    end: int
    face: str | None
    piece: int


def find_phases(
    t: np.ndarray,
    gyro: np.ndarray,
    accel: np.ndarray | None,
    opts: dict,
    *,
    dt: float,
    sigma: np.ndarray,
    spans: np.ndarray,
    source=None,
) -> FoundPhases:
    """Each face and turn found from the data, with warnings, per axis the largest rotation
    not taken for a turn, and the number of cuts found. ``dt``: the typical sample
    interval; ``sigma``: the white noise per axis; ``spans``: each sample's interval.

    The log is first split where it was cut (:func:`find_cuts`): a recording cut to its
    sections has no move between one face and the next, so a still stretch would run over
    several faces. Each piece is then cut into blocks of its own, so no block and no rest
    straddles a cut; a piece's edge where the unit is still counts as a rest's edge for the
    turns (a section cut just before or after the motion), never as a face."""
    if accel is None:
        raise SegmentationError(
            "a ferraris log needs accel_x, accel_y, accel_z to find its "
            "static faces, or a section column that names them",
            source=source,
        )
    still = _stillness(t, gyro, accel, opts, dt=dt, sigma=sigma, spans=spans, source=source)
    anchors = _anchors(still, gyro, accel, opts, len(t), dt)
    found = _turns(t, gyro, spans, still, anchors, opts, dt)
    phases = found.phases + _face_phases(still, found.phases, len(t))
    return found._replace(phases=phases, cuts=len(still.cuts))


def _stillness(t, gyro, accel, opts, *, dt, sigma, spans, source) -> Stillness:
    """Where does the unit rest, and on which face? Blocks whose gyro stays within the
    stillness limit of its resting output, in runs of ``min_still_s`` or more that no cut
    interrupts, less ``edge_s`` at both ends."""
    n = len(t)
    block = max(1, int(round(opts["block_s"] / dt))) if dt > 0 else 1
    cuts = find_cuts(t, gyro, accel, opts, dt=dt, spans=spans)
    bounds = np.r_[0, cuts, n]
    # whole blocks inside each piece (a piece's last partial block is left out)
    starts = np.concatenate(
        [np.arange(a, b - block + 1, block) for a, b in zip(bounds[:-1], bounds[1:], strict=False)]
    )
    if len(starts) < 3:
        raise SegmentationError(f"the log has {n} samples: too short for a ferraris session", source=source)
    g = gyro[starts[:, None] + np.arange(block)]  # (blocks, block, 3)
    rest_level = np.median(g.mean(axis=1), axis=0)  # the unit rests most of the time
    limit = max(opts["still_rate"], opts["still_sigmas"] * float(np.max(sigma)))
    still_block = np.abs(g - rest_level).max(axis=(1, 2)) < limit
    # a run of still blocks ends at a cut, and where a piece's partial block was left out
    block_piece = np.searchsorted(cuts, starts, side="right")
    contiguous = np.r_[False, (starts[1:] == starts[:-1] + block) & (block_piece[1:] == block_piece[:-1])]
    lo, hi = true_runs(still_block)
    runs = []
    for a, b in zip(lo, hi, strict=False):
        breaks = [int(x) for x in np.flatnonzero(~contiguous[a + 1 : b]) + a + 1]
        runs += list(zip([a] + breaks, breaks + [b], strict=False))
    min_samples = max(1, int(np.ceil(opts["min_still_s"] / (block * dt)))) * block
    edge = int(round(opts["edge_s"] / dt))
    rests = [
        (int(starts[a]) + edge, int(starts[b - 1]) + block - edge)
        for a, b in runs
        if (b - a) * block >= min_samples
    ]
    rests = [(a, b) for a, b in rests if b - a >= 2]
    if len(rests) < 2:
        raise SegmentationError(
            f"found {len(rests)} still stretch(es) of {opts['min_still_s']:g} s "
            "or more; a ferraris session rests on six faces",
            source=source,
        )
    faces = [_face_of(accel[a:b].mean(axis=0), opts["min_gravity_share"]) for a, b in rests]
    return Stillness(rests, faces, cuts, rest_level, limit, block, edge)


def _anchors(
    still: Stillness, gyro: np.ndarray, accel: np.ndarray, opts: dict, n: int, dt: float
) -> list[Anchor]:
    """What can a turn run between? The rests, and a piece's edges where the unit is still
    and no rest lies (a section that begins or ends within a block or two of the motion),
    in order."""
    cuts = still.cuts
    bounds = np.r_[0, cuts, n]
    rest_piece = np.searchsorted(cuts, [a for a, _ in still.rests], side="right")
    anchors = [
        Anchor(a, b, f, int(p)) for (a, b), f, p in zip(still.rests, still.faces, rest_piece, strict=False)
    ]
    near = 2 * still.block + still.edge
    m = edge_samples(dt)
    deviation = np.abs(gyro - still.rest_level).max(axis=1)
    share = opts["min_gravity_share"]
    for p, (a, b) in enumerate(zip(bounds[:-1], bounds[1:], strict=False)):
        if b - a < 2 * m:
            continue
        mine = [r for r, q in zip(still.rests, rest_piece, strict=False) if q == p]
        if deviation[a : a + m].min() < still.limit and not any(ra <= a + near for ra, _ in mine):
            anchors.append(Anchor(a, a, _face_of(accel[a : a + m].mean(axis=0), share), p))
        if deviation[b - m : b].min() < still.limit and not any(rb >= b - near for _, rb in mine):
            anchors.append(Anchor(b, b, _face_of(accel[b - m : b].mean(axis=0), share), p))
    anchors.sort(key=lambda x: (x[0], x[1]))
    return anchors


def _turns(t, gyro, spans, still: Stillness, anchors: list[Anchor], opts: dict, dt: float) -> FoundPhases:
    """Which chains of moves between anchors on one face are whole turns about its axis?"""
    # bias for classifying moves only (the fit estimates its own)
    bias = np.mean([gyro[a:b].mean(axis=0) for a, b in still.rests], axis=0)
    csum = np.vstack([np.zeros(3), np.cumsum((gyro - bias) * spans[:, None], axis=0)])
    found = FoundPhases([], [], {}, 0)
    i = 0
    while i < len(anchors) - 1:
        face = anchors[i].face
        if face is None:
            i += 1
            continue
        j, total = _chain_of_moves(anchors, i, face, csum, opts)
        if j > i and abs(total[AXES.index(face[1])]) > FULL_TURN / 4:
            _judge_turn(found, t, anchors[i], anchors[j], face[1], total, opts, dt)
        i = max(j, i + 1)
    return found


def _chain_of_moves(
    anchors: list[Anchor], i: int, face: str, csum: np.ndarray, opts: dict
) -> tuple[int, np.ndarray]:
    """How far does the chain of moves from anchor ``i`` (on ``face``) run on its face and
    piece, each a rotation about the face's vertical axis (else the unit was handled)? The
    last anchor of the chain and the rotation it sums to."""
    piece = anchors[i].piece
    axis = AXES.index(face[1])
    j, total = i, np.zeros(3)
    while j < len(anchors) - 1 and anchors[j + 1].face == face and anchors[j + 1].piece == piece:
        move = csum[anchors[j + 1].first] - csum[anchors[j].end]
        if abs(move[axis]) < opts["min_gravity_share"] * np.linalg.norm(move):
            break
        total += move
        j += 1
    return j, total


def _judge_turn(
    found: FoundPhases, t, start: Anchor, stop: Anchor, axis: str, total: np.ndarray, opts: dict, dt: float
) -> None:
    """A chain about ``axis`` that turns a quarter or more: a whole number of turns within
    ``angle_tolerance`` is a turn, phases and warnings taking it; otherwise the largest
    such rotation per axis is kept for the error that no turn was found."""
    a0, b0 = start.first, start.end
    a1, b1 = stop.first, stop.end
    angle = total[AXES.index(axis)]
    turns = max(1, int(round(abs(angle) / FULL_TURN)))
    off = abs(abs(angle) / (turns * FULL_TURN) - 1.0)
    t_a, t_b = float(t[min(b0, len(t) - 1)]), float(t[min(a1, len(t) - 1)])
    if off <= opts["angle_tolerance"]:
        # the turn reaches into the rests on either side, so that no slow start or
        # end of the motion is lost from its integral (the bias over them is fitted)
        # (at most half of each rest: a hand's slow start and finish lie under the
        # stillness threshold for a few tenths of a second); a piece's edge is
        # where its section was cut
        margin = int(round(opts["turn_margin_s"] / dt))
        first = max((a0 + b0) // 2, b0 - margin) if b0 > a0 else a0
        end = min((a1 + b1) // 2, a1 + margin) if b1 > a1 else a1
        found.phases.append(Phase(f"{axis}_rot", first, end))
        if turns > 1:
            found.warnings.append(
                f"the turn about {axis} at t = {t_a:.1f}–{t_b:.1f} s reads "
                f"{angle:.0f}°: taken as {turns} full turns"
            )
        return
    if abs(angle) > abs(found.largest.get(axis, 0.0)):
        found.largest[axis] = float(angle)
    if abs(angle) >= 0.75 * FULL_TURN:  # meant as a turn, surely
        found.warnings.append(
            f"a rotation about {axis} at t = {t_a:.1f}–{t_b:.1f} s reads "
            f"{angle:.0f}°, not a whole number of turns (within "
            f"{opts['angle_tolerance']:.0%}); not used"
        )


def _face_phases(still: Stillness, turns: list[Phase], n: int) -> list[Phase]:
    """Each face's observation: its longest rest, less the turns' windows, so that a face
    shares no sample with a turn."""
    turning = np.zeros(n + 1, dtype=bool)
    for _, a, b in turns:
        turning[a:b] = True
    out = []
    for label in FACES:
        mount = face_mount(label)
        mine = []
        for (a, b), f in zip(still.rests, still.faces, strict=False):
            if f == mount:
                lo, hi = true_runs(~turning[a:b])
                mine += [(int(h - s), a + int(s), a + int(h)) for s, h in zip(lo, hi, strict=False)]
        mine = [m for m in mine if m[0] >= 2]
        if mine:
            _, a, b = max(mine)
            out.append(Phase(label, a, b))
    return out


def phases_from_sections(labels: np.ndarray) -> list[Phase]:
    """Every annotated section; a label on several separate stretches keeps its longest (a
    person marks each part once)."""
    out = []
    for label in SECTIONS:
        lo, hi = true_runs(labels == label)
        if len(lo):
            k = int(np.argmax(hi - lo))
            out.append(Phase(label, int(lo[k]), int(hi[k])))
    return out


class Session(NamedTuple):
    """The samples a ferraris segmentation reads."""

    t: np.ndarray
    gyro: np.ndarray  # (n, 3)
    accel: np.ndarray | None  # (n, 3); None when the log has no accelerometer
    temp: np.ndarray
    labels: np.ndarray | None  # the section column, when the log has one
    dt: float  # the typical sample interval
    sigma: np.ndarray  # the white noise per axis
    spans: np.ndarray  # each sample's interval, up to the next one (a gap counts one interval)


class Measured(NamedTuple):
    """A phase's observation: its means over the samples, time-weighted, and the reference."""

    section: str
    kind: str  # face or turn
    t_start: float
    t_end: float
    n: int
    T: float  # s: the integration time
    gyro: np.ndarray
    temp: float
    accel: np.ndarray
    mount: str
    angle: float  # deg: the known angle (0 for a face)
    raw_angle: float  # deg: the angle the raw output integrates to
    ref_rate: float
    std: np.ndarray


def segment_ferraris(log: RigLog, options: dict) -> Segmentation:
    """The session's faces and turns as holds (module docstring); ``options`` are checked
    against the config schema and completed with its defaults."""
    opts = checked_options("ferraris", options)
    s = _read_session(log)
    if s.labels is not None and (s.labels != "").any():
        found, source = FoundPhases(phases_from_sections(s.labels), [], {}, 0), "annotation"
    else:
        found = find_phases(
            s.t, s.gyro, s.accel, opts, dt=s.dt, sigma=s.sigma, spans=s.spans, source=log.path
        )
        source = "data"
    _refuse_missing_phases(found, source, log.path)
    phases = sorted(found.phases, key=lambda p: p.first)
    rest_bias = np.mean([s.gyro[a:b].mean(axis=0) for label, a, b in phases if label in FACES], axis=0)
    rows = [_measure(phase, s, rest_bias, opts, log.path) for phase in phases]
    obs = _phase_table(rows, source, with_accel=s.accel is not None)
    info = {
        "protocol": "ferraris",
        "path": str(log.path),
        "rows_read": log.rows_read,
        "rows_dropped": log.rows_dropped,
        "rows_used": int(obs["n"].sum()),
        "sample_rate": float(1.0 / s.dt),
        "typical_hold_s": float(np.median(obs["duration"])),
        "holds_accepted": len(rows),
        "phases_from": source,
        "cuts": int(found.cuts),
        "segmentation_warnings": found.warnings,
        "white_noise": [float(x) for x in s.sigma],
    }
    return Segmentation(obs, segments_of_holds(obs, obs["section"]), no_stable_periods(), timeline(log), info)


def _read_session(log: RigLog) -> Session:
    t = log.column("t")
    gyro = np.column_stack([log.column(c) for c in GYRO]).astype(float)
    accel = (
        np.column_stack([log.column(c) for c in ACCEL]).astype(float)
        if all(c in log for c in ACCEL)
        else None
    )
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    # each sample stands for the interval up to the next one (a gap counts one interval)
    spans = np.diff(t, append=t[-1] + dt)
    spans = np.where(spans > 3 * dt, dt, spans)
    return Session(
        t, gyro, accel, log.column("temp").astype(float), read_sections(log, t), dt, white_noise(gyro), spans
    )


def _refuse_missing_phases(found: FoundPhases, source: str, path) -> None:
    """A session lacking a face or a turn is refused, naming what it lacks."""
    have = {p.label for p in found.phases}
    missing = [x for x in SECTIONS if x not in have]
    if not missing:
        return
    what = [
        f"the {face_mount(m)} face ({m[0]} {'up' if m[2] == 'p' else 'down'})"
        if m in FACES
        else f"a full turn about {m[0]}"
        + (f" (its largest rotation reads {found.largest[m[0]]:.0f}°)" if m[0] in found.largest else "")
        for m in missing
    ]
    raise SegmentationError(
        f"the session lacks {', '.join(what)}" + ("" if source == "annotation" else " (found from the data)"),
        source=path,
    )


class Reference(NamedTuple):
    """What a phase is measured against."""

    mount: str  # the axis up (a face) or turned about, with the turn's direction
    angle: float  # deg: the known angle (0 for a face)
    raw_angle: float  # deg: the angle the raw output integrates to
    ref_rate: float  # deg/s: the angle over the integration time
    std: np.ndarray  # the spread: the samples' for a face, the noise and the hand's for a turn


def _measure(phase: Phase, s: Session, rest_bias: np.ndarray, opts: dict, path) -> Measured:
    """A phase's means over its samples, each weighted by its interval, and its reference."""
    label, a, b = phase
    seg_t = s.t[a:b]
    if label in TURNS and b - a > 1 and np.max(np.diff(seg_t)) > 1.5 * s.dt:
        k = int(np.argmax(np.diff(seg_t)))
        raise SegmentationError(
            f"the turn about {label[0]} has a gap of {seg_t[k + 1] - seg_t[k]:.3g} s at "
            f"t = {seg_t[k]:.2f} s: its angle cannot be integrated",
            source=path,
        )
    w_dt = s.spans[a:b].copy()
    w_dt[-1] = s.dt  # the phase's last sample: its interval, not the one into the next phase
    T = float(w_dt.sum())
    accel = s.accel[a:b].mean(axis=0) if s.accel is not None else np.full(3, np.nan)
    if label in TURNS:
        reference = _turn_reference(phase, s, w_dt, T, accel, rest_bias, opts, path)
    else:
        reference = Reference(face_mount(label), 0.0, 0.0, 0.0, s.gyro[a:b].std(axis=0, ddof=1))
    return Measured(
        label,
        "turn" if label in TURNS else "face",
        float(seg_t[0]),
        float(seg_t[-1]),
        b - a,
        T,
        (s.gyro[a:b] * w_dt[:, None]).sum(axis=0) / T,
        float(s.temp[a:b].mean()),
        accel,
        *reference,
    )


def _turn_reference(
    phase: Phase, s: Session, w_dt: np.ndarray, T: float, accel: np.ndarray, rest_bias, opts: dict, path
) -> Reference:
    """A turn's known angle: its direction and count from the data, less the faces'
    resting output, refused unless within ``angle_tolerance`` of a whole number of turns.
    Its spread carries the hand's angle error (the turning axis' mean moves by δθ / T) and
    the unit's tilt on the table (the other two by θ δφ / T), so that std / √n is the
    mean's uncertainty."""
    label, a, b = phase
    axis = AXES.index(label[0])
    raw = float((s.gyro[a:b, axis] * w_dt).sum())
    turned = raw - rest_bias[axis] * T
    turns = max(1, int(round(abs(turned) / FULL_TURN)))
    if abs(abs(turned) / (turns * FULL_TURN) - 1.0) > opts["angle_tolerance"]:
        raise SegmentationError(
            f"the {label} section turns {turned:.0f}° about {label[0]}, not a whole "
            f"number of turns (within {opts['angle_tolerance']:.0%})",
            source=path,
        )
    angle = np.sign(turned) * turns * FULL_TURN
    up = _face_of(accel, opts["min_gravity_share"]) if s.accel is not None else None
    mount = up if up is not None and up[1] == label[0] else "+" + label[0]
    extra = np.full(3, np.deg2rad(opts["tilt_uncertainty_deg"]) * abs(angle) / T)
    extra[axis] = opts["angle_uncertainty_deg"] / T
    ref_rate = (1.0 if mount[0] == "+" else -1.0) * angle / T
    return Reference(mount, angle, raw, ref_rate, np.sqrt(s.sigma**2 + (b - a) * extra**2))


def _phase_table(rows: list[Measured], source: str, *, with_accel: bool) -> pd.DataFrame:
    """The phases as holds of the common schema, each at the session's mean temperature,
    with the ferraris columns: the accelerometer's means, the section, face or turn, the
    known and the raw angle."""
    k = len(rows)
    col = lambda key: np.array([getattr(r, key) for r in rows])  # noqa: E731
    obs = hold_table(
        t_start=col("t_start"),
        t_end=col("t_end"),
        n=col("n"),
        mount=np.array([r.mount for r in rows], dtype=object),
        mount_source=source,
        ref_rate=col("ref_rate"),
        gyro=np.vstack([r.gyro for r in rows]),
        std=np.vstack([r.std for r in rows]),
        temp=col("temp"),
        temp_rate=np.zeros(k),
        point=np.zeros(k, np.int64),
        point_temp=np.full(k, float(np.mean(col("temp")))),
    )
    obs["duration"] = col("T")  # the integration time: what the turn's rate divides by
    if with_accel:
        for i, a in enumerate(AXES):
            obs[f"accel_{a}"] = np.vstack([r.accel for r in rows])[:, i]
    obs["section"] = col("section").astype(str)
    obs["phase"] = col("kind").astype(str)
    obs["angle"] = col("angle")
    obs["raw_angle"] = col("raw_angle")
    return obs
