"""Render timings of factorloc.sim (prints figures; no assertions).

Run: ``.venv/bin/python benchmarks/bench_render.py``. Each renderer is timed
over several poses of the built-in apartment (median of N runs, after one
warm-up that bakes the texture atlas), next to a peer measured in the same
run: one bare ``cv2.remap`` of an image of the same size (the texture
sampling alone, a lower bound for any textured renderer).
"""

from __future__ import annotations

import math
import statistics
import time
from pathlib import Path

import cv2
import numpy as np

from factorloc import Pose2
from factorloc.datasets import load_scenario
from factorloc.sim import (
    DepthCamera,
    PinholeCamera,
    apartment,
    generate_scenario,
    render_camera,
    render_cloud,
    render_cloud_360,
    render_panorama,
    render_scan,
)
from factorloc.sim.textures import atlas_of

POSES = [Pose2(3.0, 2.2, 0.3), Pose2(8.0, 4.1, math.pi), Pose2(8.0, 6.0, -0.4), Pose2(1.0, 1.5, -1.2), Pose2(5.0, 6.0, 2.0)]


def _median_ms(fn, repeats: int = 4) -> tuple[float, float]:
    """Median wall-clock and CPU (this process) milliseconds per call over POSES × repeats."""
    wall, cpu = [], []
    for _ in range(repeats):
        for pose in POSES:
            t0, c0 = time.perf_counter(), time.process_time()
            fn(pose)
            wall.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
    return 1e3 * statistics.median(wall), 1e3 * statistics.median(cpu)


def _remap_ms(h: int, w: int, repeats: int = 20) -> float:
    src = atlas_of(apartment()).packed
    mx = np.random.default_rng(0).uniform(0, 4000, (h, w)).astype(np.float32)
    my = np.random.default_rng(1).uniform(0, 1800, (h, w)).astype(np.float32)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        cv2.remap(src, mx, my, cv2.INTER_LINEAR)
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


def main() -> None:
    world = apartment()
    t0 = time.perf_counter()
    atlas_of(world)
    print(f"texture atlas bake (once per world): {1e3 * (time.perf_counter() - t0):7.1f} ms")
    render_panorama(world, POSES[0])
    rng = np.random.default_rng(0)
    rows = [
        ("panorama 2048×256", _median_ms(lambda p: render_panorama(world, p, 1.0, 2048, math.radians(60))), _remap_ms(256, 2048)),
        ("camera 640×480", _median_ms(lambda p: render_camera(world, p, PinholeCamera())), _remap_ms(480, 640)),
        ("cloud 320×240 (noisy)", _median_ms(lambda p: render_cloud(world, p, DepthCamera(), rng)), None),
        ("cloud 360°, 7 views, stride 4", _median_ms(lambda p: render_cloud_360(world, p, DepthCamera(stride_px=4), rng)), None),
        ("cloud 360°, 7 views, full", _median_ms(lambda p: render_cloud_360(world, p, DepthCamera(), rng), 1), None),
        ("scan 360 beams", _median_ms(lambda p: render_scan(world, p, rng=rng)), None),
    ]
    print(f"{'renderer':32s} {'wall ms':>9s} {'CPU ms':>8s} {'bare remap ms':>14s} {'ratio':>7s}  (medians)")
    for name, (ms, cpu), peer in rows:
        if peer is None:
            print(f"{name:32s} {ms:9.1f} {cpu:8.1f} {'-':>14s} {'-':>7s}")
        else:
            print(f"{name:32s} {ms:9.1f} {cpu:8.1f} {peer:14.1f} {ms / peer:7.1f}")

    t0 = time.perf_counter()
    generate_scenario(world, 10, 1)
    print(f"generate_scenario, 10 queries: {1e3 * (time.perf_counter() - t0) / 10:7.1f} ms per query (incl. the reference once)")
    sample = Path(__file__).resolve().parents[1] / "data" / "sample"
    if (sample / "scenario.yaml").is_file():
        size = sum(f.stat().st_size for f in sample.rglob("*") if f.is_file())
        times = []
        for _ in range(5):
            t0 = time.perf_counter()
            s = load_scenario(sample)
            times.append(time.perf_counter() - t0)
        files = [f for f in sample.rglob("*") if f.suffix in (".png", ".jpg")]
        t0 = time.perf_counter()
        for f in files:
            cv2.imread(str(f))
        peer = time.perf_counter() - t0
        print(
            f"load_scenario(data/sample): {1e3 * statistics.median(times):7.1f} ms for {len(s.queries)} queries, "
            f"{size / 1e6:.2f} MB on disk; decoding its {len(files)} images alone: {1e3 * peer:.1f} ms "
            f"(ratio {statistics.median(times) / peer:.2f})"
        )


if __name__ == "__main__":
    main()
