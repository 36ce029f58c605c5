"""iSAM2 with a record of its active factors, so that it can be rebuilt after a failure."""

from __future__ import annotations

import re

import gtsam
import numpy as np

from osslam.config import BackendConfig

_KEY_IN_MESSAGE = re.compile(r"variable\s+(\d+)")


def isam2_params(cfg: BackendConfig) -> gtsam.ISAM2Params:
    """iSAM2 parameters: Gauss-Newton with wildfire, relinearisation only when requested.

    Automatic relinearisation is off: relinearising inside an update that adds factors (whose
    elimination order is constrained) makes the Bayes tree's top cliques large. The back-end
    instead relinearises in separate updates without new factors (``force_relinearize``).
    """
    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(cfg.relinearize_threshold)
    params.relinearizeSkip = 1
    params.enableRelinearization = False
    params.setOptimizationParams(gtsam.ISAM2GaussNewtonParams(cfg.wildfire_threshold))
    return params


def offending_key(exc: BaseException) -> gtsam.Symbol | None:
    """The variable named by a GTSAM exception message (e.g. an indeterminant system), if any."""
    match = _KEY_IN_MESSAGE.search(str(exc))
    return gtsam.Symbol(int(match.group(1))) if match else None


class IncrementalSolver:
    """An ``ISAM2`` instance and the factors currently in it, by factor index.

    GTSAM leaves iSAM2 half-updated when an update throws, so after a failure the solver
    is rebuilt from the recorded factors instead of being updated again.
    """

    def __init__(self, params: gtsam.ISAM2Params):
        self._params = params
        self._isam = gtsam.ISAM2(params)
        self._factors: dict[int, gtsam.NonlinearFactor] = {}

    @property
    def n_factors(self) -> int:
        """Number of factors in the graph."""
        return len(self._factors)

    def factor_indices(self) -> list[int]:
        """Indices of the factors in the graph, ascending."""
        return sorted(self._factors)

    def update(self, factors: list[gtsam.NonlinearFactor], values: gtsam.Values, remove: list[int],
               last_keys: list[int] = (), relinearize: bool = False, full_solve: bool = False) -> list[int]:
        """One iSAM2 update; returns the indices given to ``factors``. Raises what GTSAM raises.

        ``last_keys`` are eliminated last (become the root of the Bayes tree). When empty and
        factors are added, GTSAM's default applies: every variable of the new factors goes last.
        """
        graph = gtsam.NonlinearFactorGraph()
        for factor in factors:
            graph.add(factor)
        params = gtsam.ISAM2UpdateParams()
        params.removeFactorIndices = list(remove)
        params.force_relinearize = relinearize
        params.forceFullSolve = full_solve
        if last_keys:
            groups = gtsam.KeyGroupMap()
            for key in last_keys:
                groups.insert2(key, 1)
            params.constrainedKeys = groups
        result = self._isam.update(graph, values, params)
        for index in remove:
            del self._factors[index]
        indices = list(result.getNewFactorsIndices())
        self._factors.update(zip(indices, factors))
        return indices

    def rebuild(self, keep: list[int], factors: list[gtsam.NonlinearFactor],
                values: gtsam.Values) -> tuple[dict[int, int], list[int]]:
        """Replace iSAM2 by a fresh one holding the kept factors plus ``factors``.

        ``values`` must hold every variable of those factors. Returns the new index of each
        kept factor and the indices of ``factors``; on failure the solver is left unchanged.
        """
        kept = [self._factors[i] for i in keep]
        isam = gtsam.ISAM2(self._params)
        graph = gtsam.NonlinearFactorGraph()
        for factor in kept + factors:
            graph.add(factor)
        indices = list(isam.update(graph, values).getNewFactorsIndices())
        self._isam = isam
        self._factors = dict(zip(indices, kept + factors))
        return dict(zip(keep, indices[: len(keep)])), indices[len(keep):]

    def pose(self, key: int) -> np.ndarray:
        """Current estimate of a pose variable as a 4x4 matrix."""
        return self._isam.calculateEstimatePose3(key).matrix()

    def point(self, key: int) -> np.ndarray:
        """Current estimate of a point variable."""
        return self._isam.calculateEstimatePoint3(key)
