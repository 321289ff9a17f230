"""The short public calls of identify: fit a model, load one."""

from __future__ import annotations

from pathlib import Path

from identify.dataset import Dataset
from identify.dataset_checks import load_dataset
from identify.hybrid import HybridModel
from identify.hybrid_fit import fit_hybrid


def fit(dataset, **options) -> HybridModel:
    """Identify the hybrid model (Eq. 8) from a training dataset.

    Parameters
    ----------
    dataset : Dataset or str or Path
        A loaded :class:`~identify.dataset.Dataset` or a dataset folder (see
        :func:`~identify.dataset_checks.load_dataset`).
    **options
        Passed to :func:`~identify.hybrid_fit.fit_hybrid` (``folds``, ``seed``, ``arx``,
        ``ecm_method``, ``adjuster_reference``, ``progress``). Use ``fit_hybrid`` itself for the
        cross-validation tables and notes (its :class:`~identify.hybrid_fit.FitReport`).

    Returns
    -------
    HybridModel
        ``.predict(u1=..., u2=...)`` (u1 in µm/ms, u2 in µm), ``.monte_carlo(...)``,
        ``.design(volume_nl=...)``, ``.save(path)``.
    """
    ds = dataset if isinstance(dataset, Dataset) else load_dataset(dataset)
    return fit_hybrid(ds, **options).model


def load_model(path) -> HybridModel:
    """Load a model.json written by :meth:`HybridModel.save` / ``identify fit``.

    Raises
    ------
    identify.hybrid.ModelFileError
        Missing, unreadable or not a model file (the message names the file).
    """
    return HybridModel.from_json(Path(path))
