"""Simulated rig logs with ground truth, for tests, benchmarks and the demo fleet.
May import: io.

``simulate(out_dir, ...)`` writes, per unit, ``{device}.parquet`` (a log per the contract),
``{device}.truth.json`` (the parameters and the schedule that made it) and a manifest
``devices.tsv`` (contract section 3). Everything is determined by ``seed``: unit ``i`` draws
from ``SeedSequence(seed).spawn(units)[i]``.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from ..io import atomic
from ..io.errors import ConfigError
from .ferraris import FerrarisProtocol, render_ferraris
from .noise import add_coloured_noise, noise_levels
from .servo import ServoProtocol, ServoUnit, render_servo
from .sweep import SweepProtocol, SweepUnit, render_sweep
from .turntable import SEED000_RATES, SEED000_TEMPERATURES, TurntableProtocol, render
from .unit import GyroUnit

__all__ = [
    "GyroUnit",
    "TurntableProtocol",
    "SweepProtocol",
    "SweepUnit",
    "ServoProtocol",
    "ServoUnit",
    "simulate",
    "simulate_unit",
    "load_truth",
    "SEED000_RATES",
    "SEED000_TEMPERATURES",
]

# protocol -> (rig, renderer, unit): the unit class draws random units and reads truth back.
PROTOCOLS = {
    "turntable": (TurntableProtocol, render, GyroUnit),
    "sweep": (SweepProtocol, render_sweep, SweepUnit),
    "servo": (ServoProtocol, render_servo, ServoUnit),
    "ferraris": (FerrarisProtocol, render_ferraris, GyroUnit),
}
MANIFEST_COLUMNS = ("device", "batch", "session", "protocol", "path")
# protocol -> preset -> rig: "seed" the paper's schedule, "quick" a log of minutes (the
# servo's three revolutions per rotation, so each can be validated on the others).
PRESETS = {
    "turntable": {"seed": TurntableProtocol, "quick": TurntableProtocol.quick},
    "sweep": {"seed": SweepProtocol.seed003, "quick": SweepProtocol.demo},
    "servo": {"seed": ServoProtocol, "quick": lambda: ServoProtocol(revolutions=3)},
    "ferraris": {"seed": FerrarisProtocol, "quick": FerrarisProtocol},
}
# protocol -> the unit its paper publishes (turntable: seed 000 Eq 23; sweep: seed 003's
# L3GD20 sizes); the servo paper's units are drawn at random (seed 001 Section III).
PUBLISHED_UNITS = {"turntable": GyroUnit.seed000, "sweep": SweepUnit.seed003}


def rig_for(protocol: str, preset: str, knobs: dict, labels: dict | None = None):
    """The ``preset`` rig of ``protocol`` with ``knobs`` (rig fields; None: left as is)
    set; a knob the rig does not have is refused, named by ``labels`` (the CLI's options)."""
    if protocol not in PRESETS:
        raise ConfigError(
            f"protocol {protocol!r} cannot be simulated by this version of "
            f"gyrocal (supported: {', '.join(PRESETS)})"
        )
    base = PRESETS[protocol][preset]()
    given = {k: v for k, v in knobs.items() if v is not None}
    foreign = [(labels or {}).get(k, k) for k in given if k not in base.__dataclass_fields__]
    if foreign:
        raise ConfigError(f"{', '.join(foreign)} do not apply to the {protocol} rig")
    return replace(base, **given)


def published_unit(protocol: str):
    if protocol not in PUBLISHED_UNITS:
        raise ConfigError(
            f"--unit seed000 has no {protocol} counterpart: that paper's units are drawn at random"
        )
    return PUBLISHED_UNITS[protocol]()


def simulate_unit(
    path,
    *,
    protocol: str = "turntable",
    rig=None,
    unit: GyroUnit | None = None,
    rng: np.random.Generator,
    device: str = "U001",
    batch: str = "B1",
    session: str = "2026-01-01",
    seed: int | None = None,
    effects: dict | None = None,
    noise=None,
) -> dict[str, Any]:
    """Render one unit's log to ``path`` and its truth beside it; return the truth: a JSON
    document of the unit's identity, its parameters (``unit``), the rig, any coloured noise
    and the renderer's truth of the schedule (:class:`~.turntable.TurntableTruth`, ...).
    ``effects`` adds errors beyond the seed-000 model (:meth:`GyroUnit.with_effects`);
    ``noise`` (a grade or levels, :func:`gyrocal.simulate.noise.noise_levels`) adds coloured
    noise to the unit's white noise."""
    if protocol not in PROTOCOLS:
        raise ConfigError(f"unknown protocol {protocol!r}; this simulator knows {', '.join(PROTOCOLS)}")
    rig_cls, renderer, unit_cls = PROTOCOLS[protocol]
    rig = rig or rig_cls()
    unit = (unit or unit_cls.random(rng)).with_effects(effects)
    path = Path(path)
    levels = noise_levels(noise) if noise is not None else None
    # The log appears last, whole and with its noise, after its truth: a log that exists
    # is a finished one (the workflow's simulate job declares only the log).
    with atomic.replacing(path) as tmp:
        schedule = renderer(rig, unit, rng, tmp)
        if levels:
            add_coloured_noise(tmp, levels, rng)
        truth = dict(
            format="gyrocal.truth/1",
            device=device,
            batch=batch,
            session=session,
            protocol=protocol,
            seed=seed,
            unit=unit.to_dict(),
            rig=rig.to_dict(),
            **({"coloured_noise": levels} if levels else {}),
            **schedule,
        )
        atomic.write_text(truth_path(path), json.dumps(truth, indent=1) + "\n")
    return truth


def truth_path(log_path) -> Path:
    log_path = Path(log_path)
    return log_path.with_name(log_path.name.removesuffix(".parquet") + ".truth.json")


def load_truth(log_path) -> dict[str, Any]:
    """The truth :func:`simulate_unit` wrote beside ``log_path``, its ``unit`` as the unit's class."""
    truth = json.loads(truth_path(log_path).read_text())
    truth["unit"] = PROTOCOLS[truth.get("protocol", "turntable")][2].from_dict(truth["unit"])
    return truth


def simulate(
    out_dir,
    *,
    protocol: str = "turntable",
    units: int = 1,
    seed: int = 0,
    rig=None,
    unit: GyroUnit | None = None,
    batch: str = "B1",
    session: str = "2026-01-01",
    device_prefix: str = "U",
    effects: dict | None = None,
    noise=None,
) -> Path:
    """Simulate ``units`` units into ``out_dir``; return the manifest path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for i, child in enumerate(np.random.SeedSequence(seed).spawn(units)):
        device = f"{device_prefix}{i + 1:03d}"
        name = f"{device}.parquet"
        simulate_unit(
            out / name,
            protocol=protocol,
            rig=rig,
            unit=unit,
            rng=np.random.default_rng(child),
            device=device,
            batch=batch,
            session=session,
            seed=seed,
            effects=effects,
            noise=noise,
        )
        rows.append((device, batch, session, protocol, name))
    manifest = out / "devices.tsv"
    atomic.write_text(manifest, "\n".join("\t".join(r) for r in [MANIFEST_COLUMNS, *rows]) + "\n")
    return manifest
