"""Python API mirroring the CLI: `check`, `simulate`, `identify`, `sample`, `demo`,
`observability`, `design`, `diagnose`, `export`.

Each function takes paths or in-memory objects and returns a result object; the CLI commands
parse their arguments, call these and print. `identify` with `out_dir` writes exactly what
`vdsbi identify` writes.

    from vdsbi import api
    res = api.identify("drive.csv", "vehicle.json", rounds=2, sims=1000, seed=0)
    print(res.table())

The inference, diagnostics and discovery layers are imported on first use, so that the CLI
starts quickly.
"""

from ._check import CheckResult as CheckResult, check as check
from ._demo import (
    DemoBudget as DemoBudget,
    DemoResult as DemoResult,
    demo as demo,
    demo_recording as demo_recording,
    true_values as true_values,
)
from ._design import DesignReport as DesignReport, design as design
from ._diagnose import diagnose as diagnose
from ._export import (
    EXPORT_FORMATS as EXPORT_FORMATS,
    corner_masses as corner_masses,
    export as export,
    write_export as write_export,
)
from ._identify import (
    IdentifyResult as IdentifyResult,
    identify as identify,
    posterior_predictive as posterior_predictive,
    sample as sample,
)
from ._observability import ObservabilityResult as ObservabilityResult, observability as observability
from ._outputs import (
    CHECKPOINT as CHECKPOINT,
    ESTIMATOR as ESTIMATOR,
    RUN_FILE as RUN_FILE,
    checkpoint_dir as checkpoint_dir,
    output_dir as output_dir,
    plot_posterior as plot_posterior,
    summarise as summarise,
    write_atomically as write_atomically,
    write_outputs as write_outputs,
)
from ._plots import (
    display_unit as display_unit,
    drive_plot as drive_plot,
    pairplot as pairplot,
    ppc_plot as ppc_plot,
)
from ._simulate import SimulateResult as SimulateResult, simulate as simulate
from ._validate import PROFILE_V0 as PROFILE_V0
