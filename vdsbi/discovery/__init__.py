"""Mismatch discovery: locate where a recording and the model disagree, name the missing physics,
add it, re-identify θ, and show the held-out fit improve."""

from ._candidates import (
    LOOKALIKE_GROUPS as LOOKALIKE_GROUPS,
    pair_candidates as pair_candidates,
    single_candidates as single_candidates,
)
from ._data import Windows as Windows, make_windows as make_windows, noise_sigma as noise_sigma
from ._diagnose import (
    DiagnosisResult as DiagnosisResult,
    default_identify as default_identify,
    diagnose as diagnose,
    verdict as verdict,
)
from ._fit import (
    EFFECT_BOUNDS as EFFECT_BOUNDS,
    EFFECT_NAMES as EFFECT_NAMES,
    FitData as FitData,
    FitResult as FitResult,
    Fitter as Fitter,
    rk4_readings as rk4_readings,
)
from ._rank import (
    PAIR_LOG_PRIOR as PAIR_LOG_PRIOR,
    STRONG as STRONG,
    Ranked as Ranked,
    bic_score as bic_score,
    choose as choose,
    merge as merge,
    rank as rank,
    separability as separability,
)
from ._report import REQUIRED_KEYS as REQUIRED_KEYS, write_report as write_report
