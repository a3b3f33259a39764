"""The seed papers' tables, regenerated on simulated data beside their published values.
May import: io, terms, simulate, fit, report, protocols, pipeline.

Each seed has a module ``gyrocal.paper.seed<NNN>`` with ``tables(*, seed, quick)`` (a list
of :class:`~gyrocal.paper.table.PaperTable`) and ``figures(out_dir, *, seed, quick)`` (a
list of image files). They are imported by name, only when asked for, so the command line
starts fast and a seed whose module is absent is skipped with a message instead of
failing the others. ``gyrocal paper --out DIR`` writes ``tables.md``, ``tables.csv`` and
``index.html`` there (figures under ``DIR/figures``).
"""

from __future__ import annotations

import argparse
import importlib
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from ..io.errors import ConfigError

SEEDS = ("000", "001", "003")


def load(seed: str):
    """The seed's module, or None when it does not exist (a module that exists but fails
    to import raises as usual)."""
    name = f"{__name__}.seed{seed}"
    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as exc:
        if exc.name == name:
            return None
        raise


def check_seeds(seeds: Sequence[str]) -> tuple[str, ...]:
    seeds = tuple(seeds)
    unknown = [s for s in seeds if s not in SEEDS]
    if unknown or not seeds:
        raise ConfigError(
            f"expected seeds among {', '.join(SEEDS)}, found "
            f"{', '.join(repr(s) for s in unknown) if unknown else 'none'}"
        )
    return tuple(s for s in SEEDS if s in seeds)  # the papers' order, each once


def regenerate(
    out_dir,
    *,
    only: Sequence[str] = SEEDS,
    seed: int = 0,
    quick: bool = False,
    say: Callable[[str], None] = print,
) -> list[Path]:
    """Regenerate the seeds' tables and figures and render them into ``out_dir``.

    ``say`` gets one line per seed (what was made and how long it took, or why it was
    skipped); the files themselves carry no timing, so re-runs are byte-identical.
    """
    from .render import render

    out = Path(out_dir)
    tables, figures, skipped = [], {}, {}
    for s in check_seeds(only):
        module = load(s)
        if module is None:
            skipped[s] = f"module {__name__}.seed{s} is not available"
            say(f"gyrocal paper: seed {s} skipped: {skipped[s]}")
            continue
        start = time.perf_counter()
        made = list(module.tables(seed=seed, quick=quick))
        figures[s] = list(module.figures(out / "figures", seed=seed, quick=quick))
        tables += made
        say(
            f"gyrocal paper: seed {s}: {len(made)} tables, {len(figures[s])} figures in "
            f"{time.perf_counter() - start:.1f} s"
        )
    about = f"simulation seed {seed}, {'quick' if quick else 'full'} regeneration"
    return render(tables, out, figures=figures, skipped=skipped, about=about)


def _seed_list(text: str) -> tuple[str, ...]:
    try:
        return check_seeds([s.strip() for s in text.split(",") if s.strip()])
    except ConfigError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def cmd_paper(args) -> int:
    paths = regenerate(args.out, only=args.only, seed=args.seed, quick=args.quick)
    print(f"wrote {', '.join(str(p) for p in paths)}")
    return 0


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``gyrocal paper`` on the CLI's subparsers."""
    p = subparsers.add_parser(
        "paper", help="regenerate the seed papers' tables beside their published values"
    )
    p.add_argument("--out", required=True, help="folder for tables.md, tables.csv, index.html")
    p.add_argument(
        "--only",
        type=_seed_list,
        default=SEEDS,
        metavar="SEEDS",
        help=f"comma-separated seeds (default: {','.join(SEEDS)})",
    )
    p.add_argument("--seed", type=int, default=0, help="simulation seed (default 0)")
    p.add_argument(
        "--quick",
        action="store_true",
        help="small simulations that run in seconds (tests), not the papers' protocols",
    )
    p.set_defaults(func=cmd_paper)
    return p
