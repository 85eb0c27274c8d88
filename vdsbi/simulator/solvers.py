"""The integrators: `Solver(dt)` gives `RK4(dt)`, or `AdaptiveTsit5` when `dt` is None; both are
`AbstractSolver`s."""

from ._solver import (
    RK4 as RK4,
    AbstractSolver as AbstractSolver,
    AdaptiveTsit5 as AdaptiveTsit5,
    Solver as Solver,
)
