"""The forward search adds effects one at a time while the evidence gain is strong, finds a weak
effect that a strong one hides among the singles, stops at the limit, and reports look-alikes."""

from types import SimpleNamespace

import numpy as np

from vdsbi.discovery._rank import rank
from vdsbi.discovery._search import forward_search

N = 10_000
PENALTY = 0.5 * np.log(N)  # BIC cost of one parameter, in log-evidence


def _fake_fits(explained: dict[str, float], extra: dict[frozenset, float] | None = None):
    """fit_fn for a toy world: each effect lowers χ² by its own amount (additively), each
    has one parameter; `extra` adds interactions for every set containing the given ones."""
    extra = extra or {}

    def fit_fn(effects, z0):
        gain = sum(explained.get(e, 0.0) for e in effects)
        gain += sum(v for k, v in extra.items() if k <= set(effects))
        return _fit(5000.0 - gain, len(effects), effects=tuple(effects))

    return fit_fn, fit_fn((), None)


def _fit(chi2: float, k: int, tau: float = 1.0, effects: tuple = ()) -> SimpleNamespace:
    """A fit of one channel of N samples whose evidence is the white-noise χ² difference when
    τ = 1 (½·N·ln(RSS ratio) with RSS = exp(χ²/N))."""
    noise = SimpleNamespace(tau=np.array([tau]), samples=np.array([float(N)]))
    rss = np.array([np.exp(chi2 / N)])
    return SimpleNamespace(
        chi2=chi2, rss=rss, noise=noise, num_params=6 + k, num_samples=N, z=None, effects=effects
    )


def _chi2_for(log_evidence: float) -> float:
    """The χ² drop that gives one added parameter this log Bayes factor."""
    return 2 * (log_evidence + PENALTY)


def test_weak_effect_hidden_among_singles_is_added_after_the_strong_one():
    # "b" alone ranks below decoys that mimic part of "a"; on the refitted "a" model only b helps
    explained = {"a": _chi2_for(400), "b": _chi2_for(5), "c": _chi2_for(30)}
    # c is a look-alike of a: once a is in, c adds nothing (their drops overlap)
    overlap = {frozenset({"a", "c"}): -_chi2_for(30) - 2 * PENALTY}
    fit_fn, base = _fake_fits(explained, overlap)
    found = forward_search(fit_fn, base, ("a", "b", "c", "d"), max_effects=3)
    assert found.selected == ("a", "b")
    assert [s.added for s in found.steps] == ["a", "b", None]
    assert found.steps[1].gains["b"] > 3 > found.steps[1].gains["c"]
    ranked = rank(found.fits, base)
    assert ranked[0].effects == ("a", "b")  # the prior −3 per extra effect agrees with the search


def test_stops_at_the_limit_and_when_nothing_is_strong():
    explained = {"a": _chi2_for(50), "b": _chi2_for(40), "c": _chi2_for(30), "d": _chi2_for(20)}
    fit_fn, base = _fake_fits(explained)
    assert forward_search(fit_fn, base, tuple(explained), max_effects=2).selected == ("a", "b")
    assert forward_search(fit_fn, base, tuple(explained), max_effects=1).selected == ("a",)
    fit_fn, base = _fake_fits({"a": _chi2_for(2.0)})
    found = forward_search(fit_fn, base, ("a", "b"), max_effects=3)
    assert found.selected == () and found.steps[0].added is None


def test_look_alikes_are_reported_as_ambiguous():
    explained = {"a": _chi2_for(20), "b": _chi2_for(19)}  # gains within 3 of each other
    overlap = {frozenset({"a", "b"}): -_chi2_for(19)}  # together no better than one
    fit_fn, base = _fake_fits(explained, overlap)
    found = forward_search(fit_fn, base, ("a", "b"), max_effects=3)
    assert found.selected == ("a",)
    assert found.steps[0].ambiguous_with == ["b"]


def test_an_effect_that_entered_as_a_stand_in_leaves_once_the_true_ones_are_in():
    # g mimics most of a + b alone (best single), but beside both it adds nothing
    explained = {"a": _chi2_for(300), "b": _chi2_for(250), "g": _chi2_for(400)}
    overlap = {
        frozenset({"g", "a"}): -_chi2_for(250),
        frozenset({"g", "b"}): -_chi2_for(200),
        frozenset({"g", "a", "b"}): _chi2_for(250) + _chi2_for(200) - _chi2_for(400) - 2 * PENALTY,
    }
    fit_fn, base = _fake_fits(explained, overlap)
    found = forward_search(fit_fn, base, ("a", "b", "g"), max_effects=3)
    assert found.steps[0].added == "g"
    assert found.selected == ("a", "b"), found.steps
    assert any(s.removed == "g" for s in found.steps)


def test_the_search_starts_from_the_base_set_and_drops_a_default_that_stood_in():
    # identify's default "g" explains part of the drive; "a" explains it all, "g" adds nothing beside it
    explained = {"g": _chi2_for(10.0), "a": _chi2_for(40.0)}
    fit_fn, _ = _fake_fits(explained, {frozenset({"a", "g"}): -_chi2_for(10.0)})
    base = fit_fn(("g",), None)
    found = forward_search(fit_fn, base, ("a", "b"), max_effects=2)
    assert found.steps[0].current == ("g",) and found.steps[0].added == "a"
    assert found.steps[0].removed == "g" and found.selected == ("a",)
    ranked = rank(found.fits, base)
    assert ranked[0].name == "a+no g" and next(r for r in ranked if r.effects == ("g",)).score == 0.0
