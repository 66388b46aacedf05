"""factorloc's compiled kernels (numba): where they are cached, a notice when they compile, and a warm-up.

The ICP step's inner loops (:mod:`factorloc.registration`) are compiled by numba
the first time they run on a machine (tens of seconds), then loaded from numba's
on-disk cache (``cache=True``). Where that cache lives:

1. ``NUMBA_CACHE_DIR`` when the user set it;
2. else beside the sources (``factorloc/registration/__pycache__``) when that is
   writable — an editable install, a checkout;
3. else :func:`user_cache_dir` (``$XDG_CACHE_HOME/factorloc/numba``, by default
   ``~/.cache/factorloc/numba``) — a non-editable ``pip install`` into a read-only
   site-packages.

:func:`configure` applies this before the kernels are decorated
(:mod:`factorloc.registration` calls it first) and installs a listener of numba's
compile events: the first time one of factorloc's kernels compiles, one INFO line
is logged (and handed to the callbacks of :func:`on_first_compile`, which the CLI
prints). :func:`warm_up` compiles every kernel at once (``make setup`` runs it).
This module does not import numba until :func:`configure` runs.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from pathlib import Path

_log = logging.getLogger(__name__)

__all__ = ["cache_location", "configure", "on_first_compile", "user_cache_dir", "warm_up"]

_PACKAGE = Path(__file__).resolve().parent
_KERNELS = _PACKAGE / "registration"
_callbacks: list[Callable[[str], None]] = []
_state = {"configured": False, "noticed": False}


def user_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/factorloc/numba`` (``~/.cache/factorloc/numba`` when XDG_CACHE_HOME is unset)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "factorloc" / "numba"


def _writable(directory: Path) -> bool:
    pycache = directory / "__pycache__"
    target = pycache if pycache.exists() else directory
    return os.access(target, os.W_OK)


def cache_location() -> str:
    """Where the compiled kernels are (to be) cached, as a path string."""
    env = os.environ.get("NUMBA_CACHE_DIR")
    if env:
        return env
    if _writable(_KERNELS):
        return str(_KERNELS / "__pycache__")
    return str(user_cache_dir())


def on_first_compile(callback: Callable[[str], None]) -> None:
    """Call ``callback(message)`` (once per process) when the first of factorloc's kernels starts compiling."""
    _callbacks.append(callback)


def _notice(dispatcher: object) -> None:
    if _state["noticed"]:
        return
    func = getattr(dispatcher, "py_func", None)
    if not str(getattr(func, "__module__", "")).startswith("factorloc."):
        return
    _state["noticed"] = True
    msg = f"compiling factorloc's kernels for this machine (once, up to a minute; then cached in {cache_location()})"
    _log.info(msg)
    for cb in list(_callbacks):
        cb(msg)


def configure() -> None:
    """Point numba's cache at :func:`cache_location` and listen for the first compile (idempotent)."""
    if _state["configured"]:
        return
    import numba
    from numba.core import event

    if not os.environ.get("NUMBA_CACHE_DIR") and not _writable(_KERNELS):
        path = user_cache_dir()
        path.mkdir(parents=True, exist_ok=True)
        numba.config.CACHE_DIR = str(path)

    class _FirstCompile(event.Listener):
        def on_start(self, ev: event.Event) -> None:
            _notice((ev.data or {}).get("dispatcher"))

        def on_end(self, ev: event.Event) -> None:
            pass

    event.register("numba:compile", _FirstCompile())
    _state["configured"] = True


def warm_up() -> float:
    """Compile (or load) every kernel the pipeline uses, on a small synthetic room; returns the seconds it took.

    Runs the ICP step seeded and blind (global search) on a laser scan and on the cut of a
    3D cloud, which is what the steps call on real data, and the compass's kernels (:mod:`factorloc.vision._kernels`:
    windowed descriptor matching, vote consensus, the resection's RANSAC and refinement).
    """
    import numpy as np

    import factorloc as fl

    t0 = time.perf_counter()
    rng = np.random.default_rng(0)
    walls = [((0, 0), (6, 0)), ((6, 0), (6, 4)), ((6, 4), (0, 4)), ((0, 4), (0, 0)), ((2, 1.5), (3, 1.5)), ((3, 1.5), (3, 2.4))]

    def room(pose: fl.Pose2) -> np.ndarray:
        pts = []
        for a, b in walls:
            a_, b_ = np.array(a, float), np.array(b, float)
            t = rng.uniform(0, 1, (int(40 * np.linalg.norm(b_ - a_)), 1))
            pts.append(a_ + t * (b_ - a_))
        return pose.inverse().transform_points(np.vstack(pts))

    ref_pose, query_pose = fl.Pose2(1.0, 1.0, 0.2), fl.Pose2(1.3, 2.6, -0.4)
    reference = fl.Reference(scan=fl.Scan(room(ref_pose)), T_world_reference=ref_pose)
    localizer = fl.Localizer(reference)
    odometry = fl.Odometry(fl.Pose2(1.33, 2.57, -0.38), 0.05, 0.05, 0.03)
    scan = fl.Scan(room(query_pose))
    xy = room(query_pose)
    cloud = fl.PointCloud(np.column_stack([np.repeat(xy, 3, axis=0), np.tile([0.9, 1.0, 1.1], len(xy))]))
    for query in (fl.Query(scan=scan, odometry=odometry), fl.Query(cloud=cloud, odometry=odometry)):
        localizer.localize(query)
        localizer.localize(query, seeded=False)
    # the compass's seeded descriptor matching, its vote consensus and its resection (a scan-only localizer never
    # calls them)
    from factorloc.vision import keypoints as kp
    from factorloc.vision import resection as rs
    from factorloc.vision._kernels import two_nearest_in_window

    f32 = np.float32
    two_nearest_in_window(np.zeros((2, 3), f32), np.ones(3, f32), np.zeros(3, f32), np.zeros(2, f32), f32(0.5), f32(2 * np.pi))
    votes = np.array([0.1, 0.11, 0.12, 2.0])
    kp.vote_consensus(votes, 0.05)
    kp.competing_mode(votes, 0.1, 0.05)
    kp.support_rows(votes[None, :], 0.05)
    truth = fl.Pose2(0.3, -0.2, 0.4)
    pts = rng.uniform(-4.0, 4.0, (12, 2))
    d = pts - np.array([truth.x, truth.y])
    bearings = np.arctan2(d[:, 1], d[:, 0]) - truth.theta
    fit = rs.ransac(pts, bearings, 0.01)
    rs.refine(pts, bearings, fit.pose if fit is not None else truth, jackknife=True)
    seconds = time.perf_counter() - t0
    _log.info("factorloc's kernels are ready (%.1f s; cache: %s)", seconds, cache_location())
    return seconds
