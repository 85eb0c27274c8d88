"""Physics effects: the registry `EFFECTS` (name → class, in search order), `get_effect`,
`register_effect` and the `AbstractEffect` / `Context` / `Param` interface an effect implements
(one module each in `_effects/`; `promoted` for an effect that writes into the inputs), the
candidate terms `TERMS` with `term_effect` / `term_formula` that describe a mismatch as a formula,
`EffectSettings` (the effects a simulation enables and their values) and `effect_params_from`
(effect modules and parameter vectors from names and values)."""

from ._effects import (
    EFFECTS as EFFECTS,
    TERMS as TERMS,
    AbstractEffect as AbstractEffect,
    Context as Context,
    Param as Param,
    get_effect as get_effect,
    promoted as promoted,
    register_effect as register_effect,
    term_effect as term_effect,
    term_formula as term_formula,
)
from ._solve import EffectSettings as EffectSettings, effect_params_from as effect_params_from
