"""Mismatch discovery: locate where a recording and the model disagree, name the missing physics,
add it, re-identify θ, and show the held-out fit improve.

`diagnose_mismatch` runs it (how: `DiagnoseSettings`) and returns a `DiagnosisResult`;
`write_report` writes its report; `effect_names` lists the candidate effects."""

from ._candidates import effect_names as effect_names
from ._diagnose import diagnose_mismatch as diagnose_mismatch
from ._report import write_report as write_report
from ._results import DiagnosisResult as DiagnosisResult
from ._settings import DiagnoseSettings as DiagnoseSettings
