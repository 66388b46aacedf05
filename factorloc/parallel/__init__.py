"""Where batch work runs: in this process (:class:`SerialExecutor`, the default) or on a Dask cluster
(:class:`DaskExecutor`, the optional extra ``factorloc[dask]``).

The batch functions (:func:`factorloc.evaluation.evaluate`, :func:`~factorloc.evaluation.run_hierarchy`,
:func:`~factorloc.evaluation.relations.relations_benchmark`, :func:`~factorloc.evaluation.sweep.run_sweep`) take
``executor=``: an object of the :class:`Executor` protocol whose :meth:`~Executor.map_chunks` applies a function
to chunks of a list and gives the results back in input order. A chunk whose function raised, or whose worker
died, comes back as one :class:`TaskFailure` per item: the batch goes on, the caller reports the failed items.

Importing this package does not import Dask: :class:`DaskExecutor` imports ``dask.distributed`` when it starts.
"""

from factorloc.parallel.base import Executor, ItemsProgress, SerialExecutor, TaskFailure, chunk_indices
from factorloc.parallel.dask_executor import DaskExecutor, executor_from_options

__all__ = [
    "DaskExecutor",
    "Executor",
    "ItemsProgress",
    "SerialExecutor",
    "TaskFailure",
    "chunk_indices",
    "executor_from_options",
]
