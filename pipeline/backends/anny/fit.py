"""Fit anny to every person's 2D and 3D keypoints over a whole sequence (torch, L-BFGS).

The method, its passes and its loss are the body-model-independent
``fitting.sequence.fit_sequence``; anny enters it through ``fit_body.AnnyFitBody`` (shape: 6
phenotypes; keypoints: the folded COCO(+feet) regressor; anny's joint limits and GMM prior).
"""

from __future__ import annotations

import numpy as np

from pipeline.backends.anny.fit_body import AnnyFitBody
from pipeline.backends.anny.model import FIT_DTYPES, AnnyBody, anny_fit_body
from pipeline.backends.fitting.common import PersonObservations, ProgressFn
from pipeline.backends.fitting.config import FitConfig
from pipeline.backends.fitting.sequence import FitOutput, fit_sequence

__all__ = ["AnnyFitBody", "AnnyFitOutput", "PersonObservations", "anny_fit_model", "fit_anny"]

AnnyFitOutput = FitOutput
"""The anny fit's output (``fitting.sequence.FitOutput``; ``shape``: (persons, 6) phenotypes)."""


def anny_fit_model(cfg: FitConfig, body: AnnyBody | None = None) -> AnnyFitBody:
    """anny for ``fit_sequence``: ``body`` (default: the cached ``anny_fit_body(cfg.rig)``)
    at ``cfg.precision``."""
    body = anny_fit_body(cfg.rig, cfg.precision) if body is None else body.to(FIT_DTYPES[cfg.precision])
    return AnnyFitBody(body)


def fit_anny(
    observations: list[PersonObservations],
    P_px: np.ndarray,
    cfg: FitConfig,
    body: AnnyBody | None = None,
    progress: ProgressFn | None = None,
) -> FitOutput:
    """Fit shape and per-frame pose of every person (``fit_sequence`` with anny).

    Args:
        observations: one entry per person (same frame count).
        P_px: (views, 3, 4) projection matrices to *undistorted* pixels.
        cfg: the stage config (weights, iterations, robust function).
        body: the anny model (default: built from ``cfg.rig``).
    Raises ``ValueError`` on inconsistent inputs.
    """
    return fit_sequence(anny_fit_model(cfg, body), observations, P_px, cfg, progress)
