"""The on-disk scenario format and loaders for public datasets.

>>> from factorloc.datasets import load_scenario, save_scenario, Scenario   # doctest: +SKIP
>>> s = load_scenario("data/sample")                                        # doctest: +SKIP
>>> s.reference, s.queries[0].query, s.queries[0].truth, s.queries[0].faults  # doctest: +SKIP

See ``docs/data-format.md`` for the directory layout and a hand-written example. Modules:
:mod:`~factorloc.datasets.scenario` (in memory), :mod:`~factorloc.datasets.writer`,
:mod:`~factorloc.datasets.reader`.
"""

from factorloc.datasets.reader import load_scenario
from factorloc.datasets.scenario import FAULT_TAGS, FORMAT_VERSION, Scenario, ScenarioQuery, ScenarioReference
from factorloc.datasets.writer import check_scenario_target, save_scenario

__all__ = [
    "FAULT_TAGS",
    "FORMAT_VERSION",
    "Scenario",
    "ScenarioQuery",
    "ScenarioReference",
    "check_scenario_target",
    "load_scenario",
    "save_scenario",
]
