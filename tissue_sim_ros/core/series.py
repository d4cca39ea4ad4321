"""A run's implicit Euler energy as named terms, and their total: one sum for every summary, plot and table.

The energy of a step is the sum of every term the scene has (``core/physics/energy.py``): inertial, spring and
area for the paper's constraints, strain for the material, attach for a grasper's hold. A total written out
term by term drops whichever term its writer forgot (the demo once printed the inertial term of the material
scenes as their energy), so every caller names its terms once, as a mapping, and :func:`energy_total` adds
whatever the mapping holds.
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

#: Every term of the implicit Euler energy, in the order the plots and tables list them.
ENERGY_TERM_NAMES = ("inertial", "spring", "area", "strain", "attach")


def energy_total(terms: Mapping[str, np.ndarray]) -> np.ndarray:
    """The sum of every term in ``terms`` (a ``"total"`` entry, if any, is the total itself and wins)."""
    if "total" in terms:
        return np.asarray(terms["total"], dtype=np.float64)
    parts = [np.asarray(v, dtype=np.float64) for k, v in terms.items()]
    if not parts:
        raise ValueError("energy_total: no terms")
    return np.sum(parts, axis=0)


def rollout_terms(run: Any) -> dict[str, np.ndarray]:
    """The energy terms of a :class:`~tissue_sim_ros.core.sim.rollout.Rollout` (or anything with the same
    per-body arrays, shape (S, B)), by name; strain and attach only where the run has them."""
    terms = {"inertial": run.inertial, "spring": run.spring, "area": run.area}
    for name in ("strain", "attach"):
        value = getattr(run, name, None)
        if value is not None:
            terms[name] = value
    return terms


def split_remainder(listed: Mapping[str, np.ndarray], total: np.ndarray,
                    scene_terms: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Per-body terms missing from a per-body table, from its total and the scene sums of those terms.

    ``tissue/energy/bodies`` carries inertial, spring and area per body beside the total; strain and attach come
    as scene sums only (``tissue/energy/strain``, ``tissue/energy/attach``; the barrier contact's
    ``tissue/energy/contact``). The per-body remainder
    ``total - sum(listed)`` is exactly those terms together: one body takes the scene sums as they are; with
    several bodies a remainder holding one non-zero term is that term, and one holding both is shown as their sum
    ("strain + attach"), since the table cannot tell them apart per body.

    Parameters
    ----------
    listed : mapping of str to ndarray, shape (S, B)
        The terms the table gives per body.
    total : ndarray, shape (S, B)
        The table's total per body.
    scene_terms : mapping of str to ndarray, shape (S,)
        Scene sums of the terms the table leaves out (present in the run: e.g. ``{"strain": ..., "attach": ...}``).

    Returns
    -------
    dict: the missing terms per body, shape (S, B) each (empty when nothing is missing).
    """
    rest = np.asarray(total, dtype=np.float64) - energy_total(dict(listed))
    present = {k: np.asarray(v, dtype=np.float64) for k, v in scene_terms.items() if np.any(np.asarray(v) != 0.0)}
    if not present:
        return {}
    if rest.shape[1] == 1:
        return {k: v[:, None] for k, v in present.items()}
    if len(present) == 1:
        return {next(iter(present)): rest}
    return {" + ".join(present): rest}


__all__ = ["ENERGY_TERM_NAMES", "energy_total", "rollout_terms", "split_remainder"]
