"""A regenerated paper table: the published figure beside the one gyrocal computes.

Every seed module (`gyrocal.paper.seed000`, `seed001`, `seed003`) returns a list of
`PaperTable`; the renderer writes them to Markdown, CSV and HTML with the ratio
regenerated ÷ published, so agreement is read off one column.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field


@dataclass(frozen=True)
class PaperRow:
    """One figure. `published` is None where the paper prints none (a new column)."""

    label: str  # e.g. "X rotates / X axis / RMS"
    regenerated: float
    published: float | None = None
    unit: str = ""

    @property
    def ratio(self) -> float | None:
        if self.published is None or self.published == 0 or not math.isfinite(self.regenerated):
            return None
        return self.regenerated / self.published


@dataclass(frozen=True)
class PaperTable:
    seed: str  # "000", "001" or "003"
    name: str  # "Table 3", "Fig. 2 statistics"
    title: str
    rows: tuple[PaperRow, ...]
    notes: tuple[str, ...] = field(default_factory=tuple)  # set-up, and why a figure cannot agree

    @property
    def key(self) -> str:
        """File-name-safe identifier, e.g. "001-table-i"."""
        slug = "".join(c if c.isalnum() else "-" for c in self.name.lower()).strip("-")
        while "--" in slug:
            slug = slug.replace("--", "-")
        return f"{self.seed}-{slug}"
