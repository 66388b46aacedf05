"""Leave-one-log-out folds of :func:`factorloc.fit_odometry_model` on the three real laser logs.

Run: ``.venv/bin/python benchmarks/bench_odometry_model.py`` (needs ``../shared/data/laser``; ~15 s).
For each fold the model is fitted on two logs (local relations, path < 5 m) and its tails (share of
relations beyond 3σ; 0.27 % is the Gaussian's), NEES and median σ are printed on all three, the
held-out one marked. Then the same figures for the library's default model and the patent's example
(5 % drift). Prints markdown tables (docs/calibration/odometry.md); asserts nothing.
"""

from __future__ import annotations

import math
from pathlib import Path

from factorloc.datasets.rosbag import read_laser_log
from factorloc.evaluation.relations import read_relations
from factorloc.odometry_model import OdometryModel, assess_odometry_model, fit_odometry_model, odometry_residuals

LASER = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "laser"
NAMES = ("intel", "aces", "mit-csail")
#: Odometry.from_distance's defaults: the patent's example of 5 % drift
PATENT = OdometryModel(0.05, 1e-3, 0.05, 0.02, 1e-3)


def _model(m: OdometryModel) -> str:
    return (
        f"σxy = max({100 * m.min_sigma_m:.2f} cm, {100 * m.drift_ratio:.1f} %·d); "
        f"σθ = max({math.degrees(m.min_sigma_rad):.2f}°, {100 * m.heading_drift_ratio:.1f} %·r + "
        f"{math.degrees(m.heading_drift_rad_per_m):.2f}°/m·d)"
    )


def _rows(label: str, model: OdometryModel, residuals: dict, held: str | None) -> list[str]:
    out = []
    for n in NAMES:
        a = assess_odometry_model(model, residuals[n])
        role = "**held out**" if n == held else ("train" if held else "—")
        out.append(
            f"| {label} | {n} | {role} | {a.n} | {100 * a.tail_position:.2f} % | {100 * a.tail_heading:.2f} % | "
            f"{a.nees_position:.2f} | {a.nees_heading:.2f} | "
            f"{100 * a.median_sigma_m:.1f} cm | {math.degrees(a.median_sigma_rad):.2f}° |"
        )
    return out


def main() -> None:
    logs = {n: read_laser_log(LASER / f"{n}.sort.bag") for n in NAMES}
    rels = {n: read_relations(LASER / f"{n}.relations") for n in NAMES}
    res = {n: odometry_residuals(logs[n], rels[n], source=n) for n in NAMES}
    head = (
        "| model | log | role | n | beyond 3σ, position | beyond 3σ, heading | NEES position (2) | NEES heading (1) "
        "| median σxy | median σθ |\n| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"
    )
    print(head)
    models = {}
    for held in NAMES:
        train = [n for n in NAMES if n != held]
        model = fit_odometry_model([logs[n] for n in train], [rels[n] for n in train])
        models[held] = model
        print("\n".join(_rows(f"fit on {' + '.join(train)}", model, res, held)))
    print("\n".join(_rows("default OdometryModel()", OdometryModel(), res, None)))
    print("\n".join(_rows("patent example (5 %)", PATENT, res, None)))
    print()
    for held, m in models.items():
        print(f"- fit without {held}: {_model(m)}")
    print(f"- default: {_model(OdometryModel())}")
    print(f"- patent example: {_model(PATENT)}")


if __name__ == "__main__":
    main()
