"""Per-call time of ``fuse`` for both strategies on one pose with 7 estimates, and their ratio.

Run: ``.venv/bin/python benchmarks/bench_fuse.py`` (or ``make bench``). Prints figures; asserts nothing.
"""

from __future__ import annotations

import math
import statistics
import time

import numpy as np

from factorloc import Estimate, GraphFusion, Pose2, ProductFusion, fuse


def seven_estimates(rng: np.random.Generator) -> list[Estimate]:
    truth = Pose2(1.0, 0.5, math.radians(170.0))
    noisy = lambda s: rng.normal(scale=s)  # noqa: E731
    return [
        Estimate.pose(
            "odometry", Pose2(truth.x + noisy(0.05), truth.y + noisy(0.05), truth.theta + noisy(0.05)), 0.05, 0.05, 0.05
        ),
        Estimate.heading("compass", truth.theta + noisy(0.01), 0.01),
        Estimate.heading("compass2", truth.theta + noisy(0.01), 0.01),
        Estimate.heading("correlation", truth.theta + noisy(0.005), 0.005),
        Estimate.position("icp", truth.x + noisy(0.02), truth.y + noisy(0.02), 0.02, 0.02),
        Estimate.position(
            "icp2", truth.x + noisy(0.02), truth.y + noisy(0.02), covariance=np.array([[4e-4, 1e-4], [1e-4, 9e-4]])
        ),
        Estimate.pose("beacon", Pose2(truth.x + noisy(0.1), truth.y + noisy(0.1), truth.theta + noisy(0.1)), 0.1, 0.1, 0.1),
    ]


def per_call_us(fn, repeats: int = 7, calls: int = 300) -> float:  # noqa: ANN001
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(calls):
            fn()
        samples.append((time.perf_counter() - t0) / calls * 1e6)
    return statistics.median(samples)


def main() -> None:
    ests = seven_estimates(np.random.default_rng(1))
    rows = []
    for label, fn in [
        ("ProductFusion.fuse (strategy only)", lambda: ProductFusion().fuse(ests)),
        ("GraphFusion.fuse (strategy only)", lambda: GraphFusion().fuse(ests)),
        ("factorloc.fuse(..., ProductFusion()) (with gating)", lambda: fuse(ests, ProductFusion())),
        ("factorloc.fuse(..., GraphFusion()) (with gating)", lambda: fuse(ests, GraphFusion())),
    ]:
        rows.append((label, per_call_us(fn)))
    width = max(len(r[0]) for r in rows)
    print("fuse: one Pose2, 7 estimates (median of 7 × 300 calls)")
    for label, us in rows:
        print(f"  {label:<{width}}  {us:9.1f} µs/call")
    print(f"  ratio graph/product (strategy only): {rows[1][1] / rows[0][1]:.1f}×")
    print(f"  ratio graph/product (with gating):   {rows[3][1] / rows[2][1]:.1f}×")
    p, g = ProductFusion().fuse(ests), GraphFusion().fuse(ests)
    print(
        f"  agreement: |Δpose| = {np.abs(p.pose.as_array() - g.pose.as_array()).max():.2e}, "
        f"|Δcov|/|cov| = {np.abs(p.covariance - g.covariance).max() / np.abs(p.covariance).max():.2e}"
    )


if __name__ == "__main__":
    main()
