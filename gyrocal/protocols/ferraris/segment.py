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

import numpy as np
import pandas as pd

from ...io.errors import ConfigError, SegmentationError
from ...io.holds import Segmentation, hold_table, no_stable_periods, segments_of_holds, timeline, true_runs
from ...io.log import ACCEL, FACES, GYRO, SECTIONS, TURNS, RigLog, declared_units, open_dataset, time_seconds
from ...terms import AXES

FULL_TURN = 360.0


def face_mount(label: str) -> str:
    """``x_p`` → ``+x`` (x up), ``x_a`` → ``-x``."""
    return ("+" if label[2] == "p" else "-") + label[0]


def _options(options: dict) -> dict:
    known = {
        "block_s": 0.1,
        "min_still_s": 1.0,
        "still_rate": 2.0,
        "still_sigmas": 8.0,
        "edge_s": 0.1,
        "turn_margin_s": 2.0,
        "angle_tolerance": 0.15,
        "angle_uncertainty_deg": 1.0,
        "tilt_uncertainty_deg": 0.5,
        "min_gravity_share": 0.8,
        "cut_angle_deg": 45.0,
        "cut_gap_s": 0.5,
    }
    unknown = sorted(set(options) - set(known))
    if unknown:
        raise ConfigError(f"unknown ferraris option(s) {', '.join(unknown)} (known: {', '.join(known)})")
    out = {**known, **options}
    for k, v in out.items():
        if not (isinstance(v, (int, float)) and np.isfinite(v) and v >= 0):
            raise ConfigError(f"ferraris option {k} must be a number >= 0; got {v!r}")
    return out


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
    cuts = np.unique(np.concatenate(cuts)) if cuts else np.zeros(0, np.int64)
    return cuts[(cuts > 0) & (cuts < n)]


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
) -> tuple[list[tuple[str, int, int]], list[str], dict[str, float], int]:
    """(label, first row, end row) of each face and turn found from the data, warnings, per
    axis the largest rotation not taken for a turn (deg), and the number of cuts found.
    ``dt``: the typical sample interval; ``sigma``: the white noise per axis; ``spans``:
    each sample's interval.

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
    n = len(t)
    block = max(1, int(round(opts["block_s"] / dt))) if dt > 0 else 1
    cuts = find_cuts(t, gyro, accel, opts, dt=dt, spans=spans)
    bounds = np.r_[0, cuts, n]
    # whole blocks inside each piece (a piece's last partial block is left out)
    starts = np.concatenate(
        [np.arange(a, b - block + 1, block) for a, b in zip(bounds[:-1], bounds[1:], strict=False)]
    )
    nb = len(starts)
    if nb < 3:
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
    # The anchors a turn runs between: the rests, and a piece's edges where the unit is
    # still and no rest lies (a section that begins or ends within a block or two of the
    # motion). (first row, end row, face, piece)
    rest_piece = np.searchsorted(cuts, [a for a, _ in rests], side="right")
    anchors = [(a, b, f, int(p)) for (a, b), f, p in zip(rests, faces, rest_piece, strict=False)]
    near = 2 * block + edge
    m = edge_samples(dt)
    deviation = np.abs(gyro - rest_level).max(axis=1)
    for p, (a, b) in enumerate(zip(bounds[:-1], bounds[1:], strict=False)):
        if b - a < 2 * m:
            continue
        mine = [r for r, q in zip(rests, rest_piece, strict=False) if q == p]
        if deviation[a : a + m].min() < limit and not any(ra <= a + near for ra, _ in mine):
            anchors.append((a, a, _face_of(accel[a : a + m].mean(axis=0), opts["min_gravity_share"]), p))
        if deviation[b - m : b].min() < limit and not any(rb >= b - near for _, rb in mine):
            anchors.append((b, b, _face_of(accel[b - m : b].mean(axis=0), opts["min_gravity_share"]), p))
    anchors.sort(key=lambda x: (x[0], x[1]))
    # bias for classifying moves only (the fit estimates its own)
    bias = np.mean([gyro[a:b].mean(axis=0) for a, b in rests], axis=0)
    csum = np.vstack([np.zeros(3), np.cumsum((gyro - bias) * spans[:, None], axis=0)])

    warnings: list[str] = []
    phases: list[tuple[str, int, int]] = []
    largest: dict[str, float] = {}  # per axis, the largest rotation not taken for a turn
    margin = int(round(opts["turn_margin_s"] / dt))
    at = lambda i: float(t[min(i, n - 1)])  # noqa: E731
    i = 0
    while i < len(anchors) - 1:
        a0, b0, face, piece = anchors[i]
        if face is None:
            i += 1
            continue
        axis = AXES.index(face[1])
        j, total = i, np.zeros(3)
        while j < len(anchors) - 1 and anchors[j + 1][2] == face and anchors[j + 1][3] == piece:
            move = csum[anchors[j + 1][0]] - csum[anchors[j][1]]
            if abs(move[axis]) < opts["min_gravity_share"] * np.linalg.norm(move):
                break  # not a rotation about the vertical axis: the unit was handled
            total += move
            j += 1
        if j > i and abs(total[axis]) > FULL_TURN / 4:
            turns = max(1, int(round(abs(total[axis]) / FULL_TURN)))
            off = abs(abs(total[axis]) / (turns * FULL_TURN) - 1.0)
            a1, b1 = anchors[j][0], anchors[j][1]
            t_a, t_b = at(b0), at(a1)
            if off <= opts["angle_tolerance"]:
                # the turn reaches into the rests on either side, so that no slow start or
                # end of the motion is lost from its integral (the bias over them is fitted)
                # (at most half of each rest: a hand's slow start and finish lie under the
                # stillness threshold for a few tenths of a second); a piece's edge is
                # where its section was cut
                first = max((a0 + b0) // 2, b0 - margin) if b0 > a0 else a0
                end = min((a1 + b1) // 2, a1 + margin) if b1 > a1 else a1
                phases.append((f"{face[1]}_rot", first, end))
                if turns > 1:
                    warnings.append(
                        f"the turn about {face[1]} at t = {t_a:.1f}–{t_b:.1f} s reads "
                        f"{total[axis]:.0f}°: taken as {turns} full turns"
                    )
            else:
                if abs(total[axis]) > abs(largest.get(face[1], 0.0)):
                    largest[face[1]] = float(total[axis])
                if abs(total[axis]) >= 0.75 * FULL_TURN:  # meant as a turn, surely
                    warnings.append(
                        f"a rotation about {face[1]} at t = {t_a:.1f}–{t_b:.1f} s reads "
                        f"{total[axis]:.0f}°, not a whole number of turns (within "
                        f"{opts['angle_tolerance']:.0%}); not used"
                    )
        i = max(j, i + 1)
    # a face's observation shares no sample with a turn: its rest less the turns' windows
    turning = np.zeros(n + 1, dtype=bool)
    for _, a, b in phases:
        turning[a:b] = True
    for label in FACES:
        mount = face_mount(label)
        mine = []
        for (a, b), f in zip(rests, faces, strict=False):
            if f == mount:
                lo, hi = true_runs(~turning[a:b])
                mine += [(int(h - s), a + int(s), a + int(h)) for s, h in zip(lo, hi, strict=False)]
        mine = [m for m in mine if m[0] >= 2]
        if mine:
            _, a, b = max(mine)
            phases.append((label, a, b))
    return phases, warnings, largest, len(cuts)


def phases_from_sections(labels: np.ndarray) -> list[tuple[str, int, int]]:
    """(label, first row, end row) of every annotated section; a label on several separate
    stretches keeps its longest (a person marks each part once)."""
    out = []
    for label in SECTIONS:
        lo, hi = true_runs(labels == label)
        if len(lo):
            k = int(np.argmax(hi - lo))
            out.append((label, int(lo[k]), int(hi[k])))
    return out


def segment_ferraris(log: RigLog, options: dict) -> Segmentation:
    """The session's faces and turns as holds (module docstring)."""
    opts = _options(options)
    t = log.column("t")
    gyro = np.column_stack([log.column(c) for c in GYRO]).astype(float)
    accel = (
        np.column_stack([log.column(c) for c in ACCEL]).astype(float)
        if all(c in log for c in ACCEL)
        else None
    )
    temp = log.column("temp").astype(float)
    labels = read_sections(log, t)
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    sigma = white_noise(gyro)
    # each sample stands for the interval up to the next one (a gap counts one interval)
    spans = np.diff(t, append=t[-1] + dt)
    spans = np.where(spans > 3 * dt, dt, spans)
    warnings: list[str] = []
    largest: dict[str, float] = {}
    cuts = 0
    if labels is not None and (labels != "").any():
        phases, source = phases_from_sections(labels), "annotation"
    else:
        phases, warnings, largest, cuts = find_phases(
            t, gyro, accel, opts, dt=dt, sigma=sigma, spans=spans, source=log.path
        )
        source = "data"
    found = {p[0] for p in phases}
    missing = [x for x in SECTIONS if x not in found]
    if missing:
        what = [
            f"the {face_mount(m)} face ({m[0]} {'up' if m[2] == 'p' else 'down'})"
            if m in FACES
            else f"a full turn about {m[0]}"
            + (f" (its largest rotation reads {largest[m[0]]:.0f}°)" if m[0] in largest else "")
            for m in missing
        ]
        raise SegmentationError(
            f"the session lacks {', '.join(what)}"
            + ("" if source == "annotation" else " (found from the data)"),
            source=log.path,
        )
    phases.sort(key=lambda p: p[1])
    face_rows = [(a, b) for label, a, b in phases if label in FACES]
    rest_bias = np.mean([gyro[a:b].mean(axis=0) for a, b in face_rows], axis=0)
    rows = []
    for label, a, b in phases:
        seg_t = t[a:b]
        if label in TURNS and b - a > 1 and np.max(np.diff(seg_t)) > 1.5 * dt:
            k = int(np.argmax(np.diff(seg_t)))
            raise SegmentationError(
                f"the turn about {label[0]} has a gap of {seg_t[k + 1] - seg_t[k]:.3g} s at "
                f"t = {seg_t[k]:.2f} s: its angle cannot be integrated",
                source=log.path,
            )
        w_dt = spans[a:b].copy()
        w_dt[-1] = dt  # the phase's last sample: its interval, not the one into the next phase
        T = float(w_dt.sum())
        mean = (gyro[a:b] * w_dt[:, None]).sum(axis=0) / T
        row = {
            "section": label,
            "kind": "turn" if label in TURNS else "face",
            "first": a,
            "t_start": float(seg_t[0]),
            "t_end": float(seg_t[-1]),
            "n": b - a,
            "T": T,
            "gyro": mean,
            "temp": float(temp[a:b].mean()),
            "accel": accel[a:b].mean(axis=0) if accel is not None else np.full(3, np.nan),
        }
        if label in TURNS:
            axis = AXES.index(label[0])
            raw = float((gyro[a:b, axis] * w_dt).sum())
            # a turn's direction and count from the data, less the faces' resting output
            turned = raw - rest_bias[axis] * T
            turns = max(1, int(round(abs(turned) / FULL_TURN)))
            if abs(abs(turned) / (turns * FULL_TURN) - 1.0) > opts["angle_tolerance"]:
                raise SegmentationError(
                    f"the {label} section turns {turned:.0f}° about {label[0]}, not a whole "
                    f"number of turns (within {opts['angle_tolerance']:.0%})",
                    source=log.path,
                )
            angle = np.sign(turned) * turns * FULL_TURN
            up = _face_of(row["accel"], opts["min_gravity_share"]) if accel is not None else None
            mount = up if up is not None and up[1] == label[0] else "+" + label[0]
            row.update(
                mount=mount,
                angle=angle,
                raw_angle=raw,
                turns=turns,
                ref_rate=(1.0 if mount[0] == "+" else -1.0) * angle / T,
            )
            # the hand's angle error moves the turning axis' mean by δθ / T, the unit's
            # tilt on the table the other two by θ δφ / T: as spread, so that std / √n
            # is the mean's uncertainty
            extra = np.full(3, np.deg2rad(opts["tilt_uncertainty_deg"]) * abs(angle) / T)
            extra[axis] = opts["angle_uncertainty_deg"] / T
            row["std"] = np.sqrt(sigma**2 + (b - a) * extra**2)
        else:
            row.update(
                mount=face_mount(label),
                angle=0.0,
                raw_angle=0.0,
                turns=0,
                ref_rate=0.0,
                std=gyro[a:b].std(axis=0, ddof=1),
            )
        rows.append(row)
    k = len(rows)
    col = lambda key: np.array([r[key] for r in rows])  # noqa: E731
    obs = hold_table(
        t_start=col("t_start"),
        t_end=col("t_end"),
        n=col("n"),
        mount=np.array([r["mount"] for r in rows], dtype=object),
        mount_source=source,
        ref_rate=col("ref_rate"),
        gyro=np.vstack(col("gyro")),
        std=np.vstack(col("std")),
        temp=col("temp"),
        temp_rate=np.zeros(k),
        point=np.zeros(k, np.int64),
        point_temp=np.full(k, float(np.mean(col("temp")))),
    )
    obs["duration"] = col("T")  # the integration time: what the turn's rate divides by
    for i, a in enumerate(AXES):
        obs[f"accel_{a}"] = np.vstack(col("accel"))[:, i] if accel is not None else np.nan
    if accel is None:
        obs = obs.drop(columns=[f"accel_{a}" for a in AXES])
    obs["section"] = col("section").astype(str)
    obs["phase"] = col("kind").astype(str)
    obs["angle"] = col("angle")
    obs["raw_angle"] = col("raw_angle")
    segments = segments_of_holds(obs, obs["section"])
    info = {
        "protocol": "ferraris",
        "path": str(log.path),
        "rows_read": log.rows_read,
        "rows_dropped": log.rows_dropped,
        "rows_used": int(obs["n"].sum()),
        "sample_rate": float(1.0 / dt),
        "typical_hold_s": float(np.median(obs["duration"])),
        "holds_accepted": int(k),
        "phases_from": source,
        "cuts": int(cuts),
        "segmentation_warnings": warnings,
        "white_noise": [float(s) for s in sigma],
    }
    return Segmentation(obs, segments, no_stable_periods(), timeline(log), info)
