"""Layering: the core never imports the simulator, the baselines, the evaluation or the CLI; ``import factorloc`` is cheap.

Each check runs in a fresh interpreter, so that what the test session already imported does not count.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

CORE = [
    "factorloc",
    "factorloc.types",
    "factorloc.verdicts",
    "factorloc.geometry",
    "factorloc.stats",
    "factorloc.config",
    "factorloc.estimators.odometry",
    "factorloc.estimators.compass",
    "factorloc.estimators.correlation",
    "factorloc.estimators.icp",
    "factorloc.gating",
    "factorloc.fusion",
    "factorloc.pipeline",
    "factorloc.places",
    "factorloc.ros",
]
OUTSIDE_THE_CORE = ("factorloc.sim", "factorloc.baselines", "factorloc.evaluation", "factorloc.cli", "factorloc.benchmarking")


def _modules_after(code: str) -> list[str]:
    probe = f"{code}\nimport json, sys\nprint(json.dumps(sorted(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout
    return json.loads(out.splitlines()[-1])


def _loaded(modules: list[str], package: str) -> list[str]:
    return [m for m in modules if m == package or m.startswith(package + ".")]


def test_import_factorloc_loads_neither_the_simulator_nor_the_baselines_nor_the_heavy_libraries() -> None:
    modules = _modules_after("import factorloc")
    for package in (
        *OUTSIDE_THE_CORE,
        "open3d",
        "cv2",
        "gtsam",
        "numba",
        "scipy",
        "typer",
        "rich",
        "matplotlib",
        "dask",
        "distributed",
    ):
        assert not _loaded(modules, package), f"import factorloc imported {package}"


@pytest.mark.parametrize("module", CORE)
def test_the_core_does_not_import_the_layers_above_it(module: str) -> None:
    modules = _modules_after(f"import {module}\nimport factorloc\nfactorloc.localize, factorloc.Config, factorloc.GraphFusion")
    for package in OUTSIDE_THE_CORE:
        assert not _loaded(modules, package), f"{module} imported {_loaded(modules, package)}"


def test_the_scenario_format_and_the_baselines_load_the_simulator_only_when_it_is_used() -> None:
    modules = _modules_after("import factorloc.datasets, factorloc.baselines")
    assert not _loaded(modules, "factorloc.sim")
    modules = _modules_after("import factorloc.baselines as b\nb.generate_trajectory_scenario")
    assert _loaded(modules, "factorloc.sim")


def test_the_lazy_public_names_are_the_library_objects() -> None:
    import factorloc
    from factorloc.config import Config
    from factorloc.pipeline import localize

    assert factorloc.Config is Config and factorloc.localize is localize
    assert set(factorloc.__all__) <= set(dir(factorloc))
    with pytest.raises(AttributeError):
        factorloc.no_such_name  # noqa: B018
