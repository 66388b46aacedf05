"""Zero-mean normalized cross-correlation with the panorama's horizontal wrap-around.

The reference panorama is periodic in its columns; a template may straddle
azimuth ±π (column 0 / W−1). :func:`correlate_wrapped` gathers the reference
columns ``x_lo … x_hi + w − 1`` modulo ``W`` and correlates the template at
every horizontal shift ``x ∈ [x_lo, x_hi]`` (OpenCV ``TM_CCOEFF_NORMED``,
i.e. Pearson's r of template and window, in [−1, 1]).
"""

from __future__ import annotations

import cv2
import numpy as np


def correlate_wrapped(reference: np.ndarray, template: np.ndarray, x_lo: int, x_hi: int) -> np.ndarray:
    """NCC scores of ``template`` (h×w float32) over a horizontally periodic ``reference`` (H×W float32).

    Parameters
    ----------
    reference
        H×W grey image, periodic in columns.
    template
        h×w grey image with h ≤ H.
    x_lo, x_hi
        Inclusive range of horizontal shifts (any integers; taken modulo W).

    Returns
    -------
    numpy.ndarray
        (H − h + 1) × (x_hi − x_lo + 1) float32 scores; row = vertical offset,
        column k = shift ``x_lo + k`` (template column 0 on reference column
        ``(x_lo + k) mod W``).
    """
    w_ref = reference.shape[1]
    w = template.shape[1]
    idx = np.mod(np.arange(x_lo, x_hi + w), w_ref)
    window = np.ascontiguousarray(reference[:, idx])
    scores = cv2.matchTemplate(window, template, cv2.TM_CCOEFF_NORMED)
    return np.nan_to_num(scores, nan=-1.0, posinf=-1.0, neginf=-1.0)


def parabolic_peak(y_minus: float, y0: float, y_plus: float) -> tuple[float, float]:
    """Sub-sample offset and curvature of a peak from three equally spaced samples.

    Fits ``y(δ) = y0 − ½·κ·(δ − δ*)² + …`` through (−1, y₋), (0, y0), (+1, y₊):
    ``δ* = (y₋ − y₊) / (2·(y₋ − 2y0 + y₊))`` clipped to [−½, ½], ``κ = −(y₋ − 2y0 + y₊)``
    (per sample², > 0 for a maximum).
    """
    denom = y_minus - 2.0 * y0 + y_plus
    if denom >= 0.0:  # flat or not a maximum: no refinement
        return 0.0, 0.0
    delta = 0.5 * (y_minus - y_plus) / denom
    return float(np.clip(delta, -0.5, 0.5)), float(-denom)
