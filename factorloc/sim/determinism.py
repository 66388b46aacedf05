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

__all__ = ["EMULATED_CPUS", "deterministic", "without_ipp"]


#: The environment switches, per emulated CPU, that make this machine's libraries run another CPU's kernels: numpy's
#: dispatch, numba's target, OpenBLAS's kernels, OpenCV's dispatch and Intel IPP's, set before the process starts
#: (``tests/test_stability.py``, ``benchmarks/bench_cpu_paths.py``). ``"avx2"``: Haswell (AVX2 and FMA, no
#: AVX-512); ``"sse4.2"``: Nehalem (no AVX, no FMA; x86-64-v2, the oldest CPU numpy 2 runs on). A path whose
#: instructions this CPU lacks must not be run (illegal instructions).
EMULATED_CPUS: dict[str, dict[str, str]] = {
    "avx2": {
        "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",
        "NUMBA_CPU_NAME": "haswell",
        "OPENBLAS_CORETYPE": "Haswell",
        "OPENCV_CPU_DISABLE": "AVX512-SKX",
        "OPENCV_IPP": "avx2",
    },
    "sse4.2": {
        "NPY_DISABLE_CPU_FEATURES": "X86_V3 X86_V4 AVX512_ICL AVX512_SPR",
        "NUMBA_CPU_NAME": "nehalem",
        "OPENBLAS_CORETYPE": "Nehalem",
        "OPENCV_CPU_DISABLE": "AVX512-SKX,AVX2,FMA3,FP16,AVX",
        "OPENCV_IPP": "sse42",
    },
}


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
