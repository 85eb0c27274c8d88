"""The sbibm benchmarks' configs as flat dicts of named fields: what their results files store
and ``--set FIELD=VALUE`` names."""

import dataclasses

from vdsbi.inference import (
    ChannelStandardization,
    FlowMatchingSettings,
    NPEConfig,
    SplineFlowSettings,
    TrainingSettings,
)
from vdsbi.inference._config import LeakPenalty, SequentialSettings, Truncation, WeightAveraging
from vdsbi.inference._standardize import GlobalStandardization, NoStandardization, TrajectoryStandardization
from vdsbi.inference._theta_map import IdentityMap, LogitMap

#: The results files store a config flat, under these names: the spline flow's fields as they
#: are, the flow-matching estimator's with an ``fmpe_`` prefix, ``estimator`` ("nsf" or
#: "fmpe"), ``theta_map`` ("logit" or "affine"), ``x_standardize``, then the training and
#: sequential settings' fields.
_FMPE_FIELDS = {"fmpe_hidden": "hidden", "fmpe_num_blocks": "num_blocks", "fmpe_ode_steps": "ode_steps"}
_COMMON = ("theta_map", "x_standardize")
_SPLINE_FIELDS = tuple(f.name for f in dataclasses.fields(SplineFlowSettings) if f.name not in _COMMON)
_THETA_MAPS = {m.name: m for m in (LogitMap(), IdentityMap())}
#: Yes/no fields the results files store as the words they were written with: {field: (stored
#: name, {value: word})}.
_WORDS = {
    "cosine_decay": ("lr_schedule", {False: "constant", True: "cosine"}),
    "patience_over_new_data": ("patience_unit", {False: "epochs", True: "new_data"}),
}
_X_STANDARDIZE = {
    s.name: s
    for s in (
        ChannelStandardization(),
        GlobalStandardization(),
        TrajectoryStandardization(),
        NoStandardization(),
    )
}
#: Settings records stored under flat names (`_flat_records`), so results files keep their keys.
_RECORDS = ("averaging", "leak", "truncation")
#: Fields of cells run before they were removed from the library, at the value that made them no-ops.
RETIRED = {
    "retrain_from_scratch": False,
    "fmpe_time_power": 1.0,
    "min_box_mass_ratio": 0.0,
    "min_proposal_box_mass": 0.0,
    "ensemble": 1,
    "combined_loss": False,
    "truncation_widen": 1.0,
    "context_gating": False,
}


def flat_config(config: NPEConfig) -> dict:
    """``config`` as one flat dict (see `_FMPE_FIELDS`), as the results files store it."""
    flow = config.flow
    fmpe = isinstance(flow, FlowMatchingSettings)
    spline = SplineFlowSettings() if fmpe else flow
    other = flow if fmpe else FlowMatchingSettings()
    out = {k: getattr(spline, k) for k in _SPLINE_FIELDS}
    out.update({k: getattr(other, v) for k, v in _FMPE_FIELDS.items()})
    out.update(estimator="fmpe" if fmpe else "nsf", theta_map=flow.theta_map.name)
    out["x_standardize"] = flow.x_standardize.name
    for group in (config.training, config.sequential):
        out |= {f.name: getattr(group, f.name) for f in dataclasses.fields(group) if f.name not in _RECORDS}
    out |= _flat_records(config.training, config.sequential)
    for field, (stored, words) in _WORDS.items():
        out[stored] = words[out.pop(field)]
    return out


def make_config(**fields) -> NPEConfig:
    """The `NPEConfig` of the flat ``fields`` (`flat_config`'s names; the others at their defaults)."""
    f = {**flat_config(NPEConfig()), **fields}
    unknown = set(f) - set(flat_config(NPEConfig()))
    if unknown:
        raise TypeError(f"not config fields: {sorted(unknown)}")
    for field, (stored, words) in _WORDS.items():
        f[field] = {w: v for v, w in words.items()}[f.pop(stored)]
    common = dict(theta_map=_THETA_MAPS[f["theta_map"]], x_standardize=_X_STANDARDIZE[f["x_standardize"]])
    if f["estimator"] == "fmpe":
        flow = FlowMatchingSettings(**{v: f[k] for k, v in _FMPE_FIELDS.items()}, **common)
    else:
        flow = SplineFlowSettings(**{k: f[k] for k in _SPLINE_FIELDS}, **common)
    records = _records(f)
    groups = [(TrainingSettings, "training"), (SequentialSettings, "sequential")]
    kw = {
        g: cls(
            **{x.name: records[x.name] if x.name in _RECORDS else f[x.name] for x in dataclasses.fields(cls)}
        )
        for cls, g in groups
    }
    return NPEConfig(flow=flow, **kw)


def _flat_records(training: TrainingSettings, sequential: SequentialSettings) -> dict:
    """The optional records of `_RECORDS` under their flat names, an absent one at its no-op values."""
    avg, leak, trunc = training.averaging, sequential.leak, sequential.truncation
    return {
        "average_epochs": 0.0 if avg is None else avg.epochs,
        "leak_weight": 0.0 if leak is None else leak.weight,
        "leak_rows": 0 if leak is None else leak.rows,
        "leak_at_observation": False if leak is None else leak.at_observation,
        "truncation_epsilon": trunc.epsilon,
        "truncation_samples": trunc.samples,
    }


def _records(f: dict) -> dict:
    """`_flat_records` read back: the records of the flat fields ``f``."""
    if f["leak_at_observation"] and f["leak_weight"] == 0:
        raise ValueError("leak_at_observation needs leak_weight > 0 (it adds to that penalty)")
    leak = None
    if f["leak_weight"] != 0:
        leak = LeakPenalty(
            weight=f["leak_weight"], rows=f["leak_rows"], at_observation=f["leak_at_observation"]
        )
    return {
        "averaging": None if f["average_epochs"] == 0 else WeightAveraging(epochs=f["average_epochs"]),
        "leak": leak,
        "truncation": Truncation(epsilon=f["truncation_epsilon"], samples=f["truncation_samples"]),
    }
