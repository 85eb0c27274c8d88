"""The fleet: every drive of many cars answered on a Dask cluster, one amortized estimator per
vehicle platform, each answer checked against the likelihood (Pareto-smoothed importance
sampling) and escalated to a likelihood fit or the full `identify` when the check fails, and each
car's parameters followed over time by a sequential test; `diagnose` on each platform's pooled
drives names the misfit they share.

    from vdsbi.fleet import fleet
    result = fleet("manifest.csv", "out/")

Needs the ``fleet`` extra (``pip install 'vdsbi[fleet]'``: Dask.distributed).
"""

from ._amortized import AmortizedSettings as AmortizedSettings
from ._changes import ChangeSettings as ChangeSettings
from ._drive import DRAWS_FILE as DRAWS_FILE, Escalation as Escalation
from ._engine import Cluster as Cluster
from ._fleet import FleetResult as FleetResult, FleetSettings as FleetSettings, fleet as fleet
from ._misfit import Misfit as Misfit, MisfitSettings as MisfitSettings
from ._simulated import (
    TRUE_CHANGES as TRUE_CHANGES,
    TrueChange as TrueChange,
    simulated_fleet as simulated_fleet,
)
from ._windows import NoiseFamily as NoiseFamily
