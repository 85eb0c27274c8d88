"""Mismatch discovery: locate where a recording and the model disagree, name the missing physics,
add it, re-identify θ, and show the held-out fit improve."""

from ._candidates import (
    LOOKALIKE_GROUPS as LOOKALIKE_GROUPS,
    EffectSpace as EffectSpace,
    effect_names as effect_names,
    effect_space as effect_space,
    single_candidates as single_candidates,
)
from ._data import held_out_scores as held_out_scores
from ._diagnose import diagnose_mismatch as diagnose_mismatch, held_out_improves as held_out_improves
from ._fit import Fitter as Fitter
from ._rank import (
    HELD_OUT_CLAIM as HELD_OUT_CLAIM,
    PAIR_LOG_PRIOR as PAIR_LOG_PRIOR,
    STRONG as STRONG,
    bic_score as bic_score,
    choose as choose,
    merge as merge,
    rank as rank,
    separability as separability,
    verdict as verdict,
    worst_channel as worst_channel,
)
from ._report import REQUIRED_KEYS as REQUIRED_KEYS, write_report as write_report
from ._results import (
    DiagnosisResult as DiagnosisResult,
    DiscoveryFit as DiscoveryFit,
    Ranked as Ranked,
    TermDiscovery as TermDiscovery,
    Verdict as Verdict,
)
from ._search import ForwardSearch as ForwardSearch, Step as Step, forward_search as forward_search
from ._settings import DiagnoseSettings as DiagnoseSettings
from ._terms import (
    discover_terms as discover_terms,
    select_terms as select_terms,
    terms_section as terms_section,
)
