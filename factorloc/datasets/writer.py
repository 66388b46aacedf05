"""Writing a scenario directory: :func:`save_scenario` (format in ``docs/data-format.md``).

PNG and ``.npy`` are lossless, so :func:`~factorloc.datasets.reader.load_scenario` gives back an equal scenario;
clouds are stored as float32 when that is exact, else float64.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from factorloc.datasets.scenario import FORMAT_NAME, FORMAT_VERSION, Scenario, ScenarioQuery, ScenarioReference, plain
from factorloc.errors import DatasetError, InputError
from factorloc.geometry import Pose2
from factorloc.types import Panorama, Query, Reference

__all__ = ["check_scenario_target", "save_scenario"]


def check_scenario_target(path: str | Path, overwrite: bool, *, how: str = "pass overwrite=True") -> Path:
    """Check that a scenario may be written at ``path`` before any work is done; returns it as a :class:`Path`.

    A missing or empty directory may be written; a directory holding a scenario (a ``scenario.yaml``) only with
    ``overwrite``; anything else never. ``how`` is what the error message tells the user to do to replace an
    existing scenario (the CLI: ``"use --overwrite"``).
    """
    root = Path(path)
    if not root.exists():
        return root
    if not root.is_dir():
        raise InputError(f"scenario path {str(root)!r} exists and is not a directory")
    if any(root.iterdir()):
        if not overwrite:
            raise InputError(f"scenario directory {str(root)!r} is not empty ({how} to replace it)")
        if not (root / "scenario.yaml").is_file():
            raise InputError(f"refusing to overwrite {str(root)!r}: it is not empty and holds no scenario.yaml")
    return root


def save_scenario(
    scenario: Scenario,
    path: str | Path,
    *,
    image_format: str = "png",
    jpeg_quality: int = 90,
    overwrite: bool = False,
) -> Path:
    """Write ``scenario`` as a directory at ``path``; returns the path.

    Parameters
    ----------
    image_format
        ``"png"`` (lossless: :func:`load_scenario` gives back an equal scenario) or
        ``"jpg"`` for query camera images (smaller, lossy; panoramas stay PNG).
    jpeg_quality
        JPEG quality 1–100 when ``image_format="jpg"``.
    overwrite
        Replace an existing scenario directory (one that holds a ``scenario.yaml``).
    """
    if not isinstance(scenario, Scenario):
        raise InputError(f"save_scenario needs a Scenario, got {type(scenario).__name__}")
    if image_format not in ("png", "jpg"):
        raise InputError(f"image_format must be 'png' or 'jpg', got {image_format!r}")
    if isinstance(jpeg_quality, bool) or not isinstance(jpeg_quality, int) or not 1 <= jpeg_quality <= 100:
        raise InputError(f"jpeg_quality must be an integer in [1, 100], got {jpeg_quality!r}")
    root = check_scenario_target(path, overwrite)
    if root.exists() and any(root.iterdir()):  # an existing scenario, to be replaced (checked above)
        for sub in ("references", "queries"):
            if (root / sub).is_dir():
                shutil.rmtree(root / sub)
        for f in ("scenario.yaml", "world.yaml"):
            (root / f).unlink(missing_ok=True)
    root.mkdir(parents=True, exist_ok=True)

    manifest: dict[str, Any] = {
        "format": FORMAT_NAME,
        "format_version": FORMAT_VERSION,
        "name": scenario.name,
        "description": scenario.description,
        "seed": scenario.seed,
        "world": None,
        "metadata": plain(scenario.metadata),
        "references": [],
        "queries": [],
    }
    if scenario.world is not None:
        from factorloc.sim.world import save_world

        save_world(scenario.world, root / "world.yaml")
        manifest["world"] = "world.yaml"
    manifest["references"] = [_write_reference(root, entry) for entry in scenario.references]
    ext = ".png" if image_format == "png" else ".jpg"
    manifest["queries"] = [_write_query(root, entry, ext, jpeg_quality) for entry in scenario.queries]
    text = yaml.safe_dump(manifest, sort_keys=False, allow_unicode=True, width=140)
    (root / "scenario.yaml").write_text(text, encoding="utf-8")
    return root


def _write_sensors(root: Path, folder: Path, entry: dict[str, Any], sensors: Reference | Query) -> None:
    """The panorama, cloud and scan of a reference or query, written under ``folder`` and entered in ``entry``."""
    if sensors.panorama is not None:
        entry["panorama"] = _write_panorama(root, folder / "panorama.png", sensors.panorama)
    if sensors.cloud is not None:
        entry["cloud"] = _write_points(root, folder / "cloud.npy", sensors.cloud.points_m)
    if sensors.scan is not None:
        entry["scan"] = _write_points(root, folder / "scan.npy", sensors.scan.points_m)


def _write_reference(root: Path, ref_entry: ScenarioReference) -> dict[str, Any]:
    ref = ref_entry.reference
    rdir = Path("references") / ref_entry.id
    (root / rdir).mkdir(parents=True, exist_ok=True)
    r: dict[str, Any] = {"id": ref_entry.id, "name": ref.name, "T_world_reference": _pose_dict(ref.T_world_reference)}
    _write_sensors(root, rdir, r, ref)
    r["metadata"] = plain(ref_entry.metadata)
    return r


def _write_query(root: Path, qe: ScenarioQuery, ext: str, jpeg_quality: int) -> dict[str, Any]:
    q = qe.query
    qdir = Path("queries") / q.id
    (root / qdir).mkdir(parents=True, exist_ok=True)
    e: dict[str, Any] = {
        "id": q.id,
        "timestamp_s": qe.timestamp_s,
        "reference": qe.reference_id,
        "truth": None if qe.truth is None else _pose_dict(qe.truth),
        "odometry": None,
        "faults": list(qe.faults),
        "distance_from_reference_m": qe.distance_from_reference_m,
        "images": [],
    }
    if q.odometry is not None:
        o = q.odometry
        e["odometry"] = {
            **_pose_dict(o.T_world_robot),
            "sigma_x_m": o.sigma_x_m,
            "sigma_y_m": o.sigma_y_m,
            "sigma_theta_rad": o.sigma_theta_rad,
        }
    for i, im in enumerate(q.images):
        rel = qdir / f"image{i}{ext}"
        _write_image(root / rel, im.image_bgr, jpeg_quality)
        e["images"].append(
            {
                "file": rel.as_posix(),
                "width_px": im.width_px,
                "height_px": im.height_px,
                "hfov_rad": im.hfov_rad,
                "yaw_in_robot_rad": im.yaw_in_robot_rad,
                "pitch_rad": im.pitch_rad,
                "cx_px": im.cx_px,
            }
        )
    _write_sensors(root, qdir, e, q)
    e["metadata"] = plain(qe.metadata)
    return e


def _pose_dict(p: Pose2) -> dict[str, float]:
    return {"x_m": p.x, "y_m": p.y, "theta_rad": p.theta}


def _write_image(path: Path, image_bgr: np.ndarray, jpeg_quality: int) -> None:
    if path.suffix == ".png":
        ok, buf = cv2.imencode(".png", image_bgr, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    else:
        ok, buf = cv2.imencode(".jpg", image_bgr, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
    if not ok:
        raise DatasetError(f"could not encode image {str(path)!r}")
    path.write_bytes(buf.tobytes())


def _write_panorama(root: Path, rel: Path, pano: Panorama) -> dict[str, Any]:
    _write_image(root / rel, pano.image_bgr, 100)
    entry = {
        "file": rel.as_posix(),
        "width_px": pano.width_px,
        "height_px": pano.height_px,
        "fov_v_rad": pano.fov_v_rad,
        "azimuth_col0_rad": pano.azimuth_col0_rad,
    }
    if pano.seen_columns is not None:  # absent: every column seen (manifests without the field read the same)
        entry["seen_columns"] = _column_runs(pano.seen_columns)
    return entry


def _column_runs(seen: np.ndarray) -> list[list[int]]:
    """``[[start, stop), …]`` of the runs of True in a bool mask (the manifest form of ``Panorama.seen_columns``)."""
    d = np.diff(np.concatenate([[0], seen.astype(np.int8), [0]]))
    return [[int(a), int(b)] for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True)]


def _write_points(root: Path, rel: Path, points: np.ndarray) -> dict[str, Any]:
    p32 = points.astype(np.float32)
    data = p32 if np.array_equal(p32.astype(np.float64), points) else np.asarray(points, np.float64)
    np.save(root / rel, data, allow_pickle=False)
    return {"file": rel.as_posix(), "points": int(points.shape[0])}
