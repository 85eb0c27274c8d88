"""Python API mirroring the CLI: `check`, `simulate`, `identify`, `sample`, `demo`,
`observability`, `design`, `diagnose`, `export`.

Each function takes paths or in-memory objects and returns a result object; the CLI commands
parse their arguments, call these and print. `identify` with `out_dir` writes exactly what
`vdsbi identify` writes.

    from vdsbi import api
    res = api.identify("drive.csv", "vehicle.json", api.IdentifyOptions(seed=0))
    print(res.table())

What the commands write and draw is in `vdsbi.api.outputs` (the identify folder's files, the
export formats) and `vdsbi.api.plots` (figures). The inference, diagnostics and discovery
layers are imported on first use, so that the CLI starts quickly; `diagnose` returns
`vdsbi.discovery.DiagnosisResult`.
"""

from . import outputs as outputs, plots as plots
from ._check import CheckResult as CheckResult, check as check
from ._demo import DemoBudget as DemoBudget, DemoResult as DemoResult, demo as demo
from ._design import DesignReport as DesignReport, design as design
from ._diagnose import diagnose as diagnose
from ._export import export as export
from ._identify import identify as identify
from ._identify_result import IdentifyResult as IdentifyResult
from ._observability import ObservabilityResult as ObservabilityResult, observability as observability
from ._options import (
    Budget as Budget,
    DriveOptions as DriveOptions,
    IdentifyOptions as IdentifyOptions,
    ModelOptions as ModelOptions,
    Progress as Progress,
)
from ._predict import PredictResult as PredictResult, predict as predict
from ._sample import sample as sample
from ._simulate import SimulateResult as SimulateResult, simulate as simulate
