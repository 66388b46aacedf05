"""How much of the tracker's heading error is the simulator's own sensor-pose error (a diagnostic of the tours).

Every simulated scan is taken from ``T_world_robot · δ`` with one sensor-pose error δ per scan
(:func:`factorloc.sim.render_scan`, 1.4 cm and 0.25° per axis, calibrated on the real logs). A place's reference
scan carries its δ_r (the map states the place's pose, the scan was taken δ_r off it) and every query scan its δ_q.
A scan-matching estimate of the query's heading against a place then errs by about ``δq,θ − δr,θ``: no
estimator that uses one query scan and these places can do better on average. This script records each scan's
δ (it wraps the simulator's ray caster, ``factorloc.sim.laser.cast_all``, to see the sensor pose each scan was cast
from; the library is not changed), runs the default tracker on a tour, and for its unflagged results compares the
heading error with the floor ``δq,θ − mean(δr,θ over the places used)``.

Usage::

    nice -n 10 .venv/bin/python benchmarks/bench_track_floor.py --world office --seeds 1 2 3
    nice -n 10 .venv/bin/python benchmarks/bench_track_floor.py --world apartment --seeds 1 2 3
"""

from __future__ import annotations

import argparse
import math

import numpy as np

import factorloc.sim.laser as laser
import factorloc.sim.track as track
from factorloc.places import Tracker, TrackerConfig
from factorloc.sim import world_by_name


class _SensorPoses:
    """Each rendered scan's (T_world_robot, T_world_sensor), in rendering order."""

    def __init__(self) -> None:
        self.pairs: list = []
        self._cast = laser.cast_all
        self._render = laser.render_scan

    def install(self) -> None:
        cast_poses: list = []

        def cast(world, occluders, T_world_sensor, *a, **k):  # noqa: ANN001, ANN002, ANN003, ANN202 - a transparent wrapper
            cast_poses.append(T_world_sensor)
            return self._cast(world, occluders, T_world_sensor, *a, **k)

        def render(world, T_world_robot, *a, **k):  # noqa: ANN001, ANN002, ANN003, ANN202 - a transparent wrapper
            n = len(cast_poses)
            scan = self._render(world, T_world_robot, *a, **k)
            self.pairs.append((T_world_robot, cast_poses[n]))
            return scan

        laser.cast_all = cast
        track.render_scan = render

    def heading_errors_deg(self, start: int, stop: int) -> list[float]:
        return [math.degrees(math.remainder(s.theta - r.theta, 2 * math.pi)) for r, s in self.pairs[start:stop]]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--world", default="office")
    ap.add_argument("--seeds", type=int, nargs="*", default=[1, 2, 3])
    ap.add_argument("--queries", type=int, default=200)
    ap.add_argument("--kidnaps", type=int, default=3)
    ap.add_argument("--place-spacing", type=float, default=1.5)
    args = ap.parse_args()
    poses = _SensorPoses()
    poses.install()
    world = world_by_name(args.world)
    place_map = track.room_places(world, args.place_spacing, seed=0)
    place_err = dict(zip(place_map.ids, poses.heading_errors_deg(0, len(place_map)), strict=True))
    rms_places = float(np.sqrt(np.mean(np.square(list(place_err.values())))))
    print(f"{world.name}: {len(place_map)} places, their reference scans' heading error rms {rms_places:.3f}°")
    print(
        f"{'seed':>4} {'n':>4} {'RMSE deg':>8} {'floor deg':>9} {'own deg':>7} {'corr':>5} "
        f"{'query δ rms':>11} {'places δ rms':>12} {'E = a·δq + b·mean δr':>22}"
    )
    for seed in args.seeds:
        n0 = len(poses.pairs)
        sc = track.generate_track(world, place_map, args.queries, 1000 + seed, kidnaps=args.kidnaps)
        q_err = poses.heading_errors_deg(n0, len(poses.pairs))
        if len(q_err) != len(sc.queries):
            raise RuntimeError(f"{len(q_err)} scans rendered for {len(sc.queries)} queries: the tour renders other scans")
        tracker = Tracker(place_map, TrackerConfig())
        e, dq, dr = [], [], []
        for q, d in zip(sc.queries, q_err, strict=True):
            r = tracker.update(q.query)
            if r.flagged or not r.places_used:
                continue
            e.append(math.degrees(math.remainder(r.pose.theta - q.truth.theta, 2 * math.pi)))
            dq.append(d)
            dr.append(float(np.mean([place_err[p] for p in r.places_used])))
        e_, dq_, dr_ = np.array(e), np.array(dq), np.array(dr)
        floor = dq_ - dr_
        a, b, _ = np.linalg.lstsq(np.column_stack([dq_, dr_, np.ones_like(dq_)]), e_, rcond=None)[0]
        print(
            f"{1000 + seed:>4} {len(e_):>4} {np.sqrt(np.mean(e_**2)):>8.3f} {np.sqrt(np.mean(floor**2)):>9.3f} "
            f"{np.sqrt(np.mean((e_ - floor) ** 2)):>7.3f} {np.corrcoef(e_, floor)[0, 1]:>5.2f} {np.sqrt(np.mean(dq_**2)):>11.3f} "
            f"{np.sqrt(np.mean(dr_**2)):>12.3f} {f'{a:.2f}·δq {b:+.2f}·δr':>22}",
            flush=True,
        )


if __name__ == "__main__":
    main()
