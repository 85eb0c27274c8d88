"""Mismatch discovery: locate where a recording and the model disagree, name the missing physics,
add it, re-identify θ, and show the held-out fit improve."""

from ._candidates import (
    LOOKALIKE_GROUPS as LOOKALIKE_GROUPS,
    EffectSpace as EffectSpace,
    effect_names as effect_names,
    effect_space as effect_space,
    pair_candidates as pair_candidates,
    single_candidates as single_candidates,
)
from ._data import fit_data as fit_data, held_out_metrics as held_out_metrics
from ._diagnose import (
    DiagnoseSettings as DiagnoseSettings,
    DiagnosisResult as DiagnosisResult,
    default_identify as default_identify,
    diagnose as diagnose,
)
from ._fit import FitData as FitData, FitResult as FitResult, Fitter as Fitter
from ._rank import (
    HELD_OUT_CLAIM as HELD_OUT_CLAIM,
    PAIR_LOG_PRIOR as PAIR_LOG_PRIOR,
    STRONG as STRONG,
    Ranked as Ranked,
    bic_score as bic_score,
    choose as choose,
    merge as merge,
    rank as rank,
    separability as separability,
    verdict as verdict,
    worst_channel as worst_channel,
)
from ._report import REQUIRED_KEYS as REQUIRED_KEYS, write_report as write_report
from ._search import ForwardSearch as ForwardSearch, Step as Step, forward_search as forward_search
from ._terms import (
    TermDiscovery as TermDiscovery,
    discover_terms as discover_terms,
    select_terms as select_terms,
    terms_section as terms_section,
)
