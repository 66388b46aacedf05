"""One module per estimator of the patent's hierarchy.

Each module holds a frozen ``*Config`` dataclass, a pure ``estimate(...)``
function returning an :class:`~factorloc.types.Estimate`, and a small
``*Step`` class that plugs it into :func:`factorloc.localize` through the
:class:`~factorloc.estimators.base.Step` protocol.
"""
