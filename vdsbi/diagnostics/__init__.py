"""Diagnostics for posterior estimates."""

from ._c2st import c2st as c2st
from ._calibration import (
    expected_coverage as expected_coverage,
    sbc_ks_pvalues as sbc_ks_pvalues,
    sbc_ranks as sbc_ranks,
)
from ._combinations import (
    determined_directions as determined_directions,
    vehicle_combinations as vehicle_combinations,
)
from ._design import (
    check_limits as check_limits,
    design_maneuver as design_maneuver,
    design_problem as design_problem,
)
from ._fisher import (
    MeasurementModel as MeasurementModel,
    model_fisher as model_fisher,
    score_fisher_mc as score_fisher_mc,
)
from ._fisher_report import fisher_report as fisher_report, report_markdown as report_markdown
from ._identifiability import (
    MAX_STD_RATIO as MAX_STD_RATIO,
    held_by_box as held_by_box,
    identifiability as identifiability,
)
from ._maneuver import Limits as Limits, Maneuver as Maneuver
from ._misspecification import (
    Localisation as Localisation,
    MisspecificationTest as MisspecificationTest,
    locate_mismatch as locate_mismatch,
    misspecification_test as misspecification_test,
)
from ._ridges import ridge_sentence as ridge_sentence, trading_pairs as trading_pairs
