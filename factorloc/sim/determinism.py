"""Seed-only output: the simulator's OpenCV calls run without Intel IPP.

OpenCV hands some filters (``filter2D`` with 17–19 px kernels, as the motion-blur fault uses; remap,
Gaussian blur) to Intel IPP, which picks its kernel by the CPU at run time: the same call gives other
pixels on an AVX2 machine than on an AVX-512 one (measured: the sample scenario's ``q0015`` image, by
``OPENCV_IPP=avx2`` on an AVX-512 CPU). With IPP off, OpenCV's own code runs, and ``factorloc simulate
--seed 103`` rewrites the shipped sample byte for byte under AVX-512, AVX2 (``OPENCV_IPP=avx2``,
``OPENCV_CPU_DISABLE`` of the AVX-512 dispatch, ``NPY_DISABLE_CPU_FEATURES="X86_V4 AVX512_ICL AVX512_SPR"``,
``NUMBA_CPU_NAME=haswell``) and with one thread. On an SSE4.2-only CPU (the same switches one level
lower) two images differ by one grey level in 2 and 35 pixels: floating-point rounding without FMA, which
the sample test allows for (``tests/datasets/test_sample.py``).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import ParamSpec, TypeVar

import cv2

P = ParamSpec("P")
R = TypeVar("R")

__all__ = ["deterministic", "without_ipp"]


@contextmanager
def without_ipp() -> Iterator[None]:
    """Run the enclosed OpenCV calls without IPP, restoring the caller's setting afterwards (not thread-safe:
    IPP use is a process-wide OpenCV setting)."""
    before = cv2.ipp.useIPP()
    cv2.ipp.setUseIPP(False)
    try:
        yield
    finally:
        cv2.ipp.setUseIPP(before)


def deterministic(func: Callable[P, R]) -> Callable[P, R]:
    """Decorate a simulator entry point so that its OpenCV calls run :func:`without_ipp`."""

    @functools.wraps(func)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
        with without_ipp():
            return func(*args, **kwargs)

    return wrapper
