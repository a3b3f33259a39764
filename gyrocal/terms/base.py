"""The three effects of the seed-000 error model (Eq 11-15): bias, scale, misalignment.

Seed 000 writes ``w = K w~ + B`` with ``K = K_T' C_b^n M`` (Eq 11): scale factors on the
diagonal, package misalignment and non-orthogonality off it. Here the error ``w - w~`` is
modelled, so the scale coefficient is the scale-factor error ``K_aa - 1``. The seed's
names (``K_yx`` multiplies ``w~_y`` in the x output, Eq 15) map to
``misalignment.x.y`` = K[x, y]: output axis first, input axis second.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import AXES, Term, register_term


@register_term("bias")
@dataclass(frozen=True)
class Bias(Term):
    """Constant output offset per axis, B in Eq 12. [deg/s]"""

    unit = "deg/s"

    def coefficients(self) -> list[str]:
        return [f"bias.{a}" for a in AXES]

    def columns(self, data):
        ones = np.ones(len(data["rate_x"]))
        return {f"bias.{a}": ones for a in AXES}


@register_term("scale")
@dataclass(frozen=True)
class Scale(Term):
    """Scale-factor error per axis, K_aa - 1 in Eq 11 (seed 000 Fig. 4). [1]"""

    unit = "1"
    needs = frozenset({"rate_x", "rate_y", "rate_z"})

    def coefficients(self) -> list[str]:
        return [f"scale.{a}" for a in AXES]

    def columns(self, data):
        return {f"scale.{a}": np.asarray(data[f"rate_{a}"], dtype=float) for a in AXES}


@register_term("misalignment")
@dataclass(frozen=True)
class Misalignment(Term):
    """Cross-axis sensitivity, K_ab for a != b in Eq 11: package misalignment (Eq 6) and
    non-orthogonality (Eq 7) together; ``misalignment.a.b`` is seed 000's K_ba. [1]"""

    unit = "1"
    needs = frozenset({"rate_x", "rate_y", "rate_z"})

    def coefficients(self) -> list[str]:
        return [f"misalignment.{a}.{b}" for a in AXES for b in AXES if a != b]

    def columns(self, data):
        return {
            f"misalignment.{a}.{b}": np.asarray(data[f"rate_{b}"], dtype=float)
            for a in AXES
            for b in AXES
            if a != b
        }
