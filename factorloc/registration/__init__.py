"""2D scan registration: the machinery of the ICP step (:mod:`factorloc.estimators.icp`).

- :mod:`~factorloc.registration.scan2d` — the patent's horizontal cut of a 3D cloud, voxel grid, line normals,
  free-space profile;
- :mod:`~factorloc.registration.icp2d` — point-to-line ICP with a robust kernel and a shrinking gate;
- :mod:`~factorloc.registration.kernels` — robust kernels (strategy objects);
- :mod:`~factorloc.registration.covariance` — Censi, Hessian, geometry-spread bias and Chamfer covariances;
- :mod:`~factorloc.registration.global_search` — correlative scan matcher for global initialization;
- :mod:`~factorloc.registration.open3d_peer` — Open3D's ICP on 2D scans, the peer we compare with.
"""

from factorloc.registration import _numba  # noqa: F401 - sets numba's cache directory before the kernels below
from factorloc.registration.covariance import bias_covariance, censi_covariance, chamfer_covariance, hessian_covariance
from factorloc.registration.global_search import Candidate, GlobalSearchParams, reference_fields, search
from factorloc.registration.icp2d import IcpParams, IcpResult, PreparedScan, align, prepare_target
from factorloc.registration.kernels import L2, Cauchy, Huber, RobustKernel, Tukey, kernel_from_name
from factorloc.registration.scan2d import ScanExtraction, extract_scan, free_space_violation, polar_profile, voxel_downsample_2d

__all__ = [
    "L2",
    "Candidate",
    "Cauchy",
    "GlobalSearchParams",
    "Huber",
    "IcpParams",
    "IcpResult",
    "PreparedScan",
    "RobustKernel",
    "ScanExtraction",
    "Tukey",
    "align",
    "bias_covariance",
    "censi_covariance",
    "chamfer_covariance",
    "extract_scan",
    "free_space_violation",
    "hessian_covariance",
    "kernel_from_name",
    "polar_profile",
    "prepare_target",
    "reference_fields",
    "search",
    "voxel_downsample_2d",
]
