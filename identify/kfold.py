"""Grouped K-fold cross-validation: the one fold assignment of :mod:`identify`.

Groups (whole sequences for the ARX structure selection, repeated measurements of one
control pair (u1, u2) for the polynomials) are never split between folds. The groups are
shuffled with ``numpy.random.default_rng(seed).permutation`` and dealt to
``k = min(folds, n_groups)`` folds in one of two layouts:

``"round_robin"`` (default)
    the i-th shuffled group goes to fold ``i mod k`` (polynomial order selection);
``"contiguous"``
    the shuffled groups are cut into ``k`` consecutive blocks of nearly equal size
    (``numpy.array_split``; ARX structure selection).

Both layouts give folds whose sizes differ by at most one group; they are kept apart
because each caller's published results depend on its layout.
"""

from __future__ import annotations

import numpy as np

__all__ = ["FOLD_LAYOUTS", "assign_folds", "grouped_kfold", "group_ids"]

#: Ways of dealing the shuffled groups to the folds (see the module docstring).
FOLD_LAYOUTS = ("round_robin", "contiguous")


def assign_folds(n_groups: int, folds: int, seed: int, *, layout: str = "round_robin") -> tuple[np.ndarray, int]:
    """Fold index of each of ``n_groups`` groups.

    Parameters
    ----------
    n_groups : int
        Number of groups (>= 1).
    folds : int
        Requested number of folds; ``min(folds, n_groups)`` are used.
    seed : int
        Seed of the shuffle.
    layout : {"round_robin", "contiguous"}
        How the shuffled groups are dealt to the folds (module docstring).

    Returns
    -------
    fold_of_group : ndarray of int, shape (n_groups,)
        Fold of each group, in ``0 .. k-1``.
    k : int
        Number of folds used.
    """
    if layout not in FOLD_LAYOUTS:
        raise ValueError(f"layout must be one of {FOLD_LAYOUTS}, got {layout!r}")
    n_groups = int(n_groups)
    k = min(int(folds), n_groups)
    order = np.random.default_rng(seed).permutation(n_groups)
    fold_of_group = np.empty(n_groups, dtype=int)
    if layout == "round_robin":
        fold_of_group[order] = np.arange(n_groups) % k
    else:
        for f, idx in enumerate(np.array_split(order, k)):
            fold_of_group[idx] = f
    return fold_of_group, k


def grouped_kfold(groups, folds: int, seed: int, *, layout: str = "round_robin") -> list[np.ndarray]:
    """Split sample indices into folds, keeping the samples of one group together.

    Parameters
    ----------
    groups : array_like, shape (n,) or (n, m)
        Group label of each sample (rows are compared whole, e.g. (u1, u2) pairs).
    folds : int
        Requested number of folds; at most the number of distinct groups are used.
    seed : int
        Seed of the shuffle.
    layout : {"round_robin", "contiguous"}
        See :func:`assign_folds`.

    Returns
    -------
    list of ndarray
        Sample indices held out in each fold.
    """
    uniq, inv = np.unique(groups, return_inverse=True, axis=0)
    inv = np.asarray(inv).ravel()
    fold_of_group, k = assign_folds(len(uniq), folds, seed, layout=layout)
    return [np.flatnonzero(fold_of_group[inv] == f) for f in range(k)]


def group_ids(groups) -> tuple[np.ndarray, int]:
    """Group of each sample, numbered in order of first appearance, and the number of groups.

    Parameters
    ----------
    groups : array_like, shape (n,) or (n, m)
        Group label of each sample (rows are compared whole, e.g. a table's settings).

    Returns
    -------
    ids : ndarray of int, shape (n,)
        ``0`` for the first sample's group, ``1`` for the next new one, ...: where no label
        repeats, ``ids`` is ``arange(n)`` (a split of the groups is then the same split of the
        samples; `identify.tabular` relies on it).
    n_groups : int
    """
    g = np.asarray(groups)
    if g.shape[0] == 0:
        return np.zeros(0, dtype=int), 0
    _, first, inv = np.unique(g, return_index=True, return_inverse=True, axis=0)
    rank = np.empty(first.size, dtype=int)
    rank[np.argsort(first, kind="stable")] = np.arange(first.size)
    return rank[np.asarray(inv).ravel()], int(first.size)
