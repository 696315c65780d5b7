"""Whether a loss had flattened (:func:`evaluators.metrics.convergence.convergence`), on
curves whose answer is known in closed form."""

from __future__ import annotations

import math
import statistics

import pytest

from evaluators.metrics.convergence import convergence


def test01_exponential_decay_flattens_only_late() -> None:
    # loss = exp(-t / 10) over 100 points: windows of 10; the last (t = 90..99) is the middle
    # one (t = 45..54) shifted by 45, so it is exp(-4.5) of it, and the last tenth exp(-1)
    # of the one before.
    short = convergence([math.exp(-t / 10) for t in range(100)])
    assert short["flattened"] is False
    assert short["second_half_drop"] == pytest.approx(1 - math.exp(-4.5), rel=1e-9)
    assert short["last_tenth_drop"] == pytest.approx(1 - math.exp(-1.0), rel=1e-9)
    assert "fell" in short["why"]
    plateau = convergence([1.0 + math.exp(-t / 10) for t in range(1000)])
    assert plateau["flattened"] is True and plateau["second_half_drop"] < 1e-12


def test02_annealed_but_under_trained_is_not_flat() -> None:
    """Steady progress, then a plateau only in the last tenth (a schedule annealed to zero):
    the end is flat, the second half is not."""
    curve = [1.0 - 0.5 * t / 90 for t in range(90)] + [0.5] * 10
    out = convergence(curve)
    assert out["last_tenth_drop"] == pytest.approx(1 - 0.5 / statistics.fmean(curve[80:90]))
    assert out["flattened"] is False and out["second_half_drop"] > 0.3


def test03_rising_constant_and_tolerance() -> None:
    rising = convergence([1.0] * 18 + [2.0, 2.0])
    assert rising["flattened"] is False and rising["second_half_drop"] == pytest.approx(-1.0)
    assert "rose" in rising["why"]
    assert convergence([0.5] * 10)["flattened"] is True
    # windows of 2 points: the middle two at 1.0, the last two at 0.95: a 5 % drop
    curve = [1.0] * 11 + [0.95] * 9
    assert convergence(curve)["second_half_drop"] == pytest.approx(0.05)
    assert convergence(curve, tolerance=0.1)["flattened"] is True
    assert convergence(curve, tolerance=0.02)["flattened"] is False


def test04_no_verdict() -> None:
    assert convergence([1.0, 0.5, 0.2])["flattened"] is None
    assert convergence([])["flattened"] is None
    diverged = convergence([1.0, 0.5, 0.2, 0.1, float("nan")])
    assert diverged["flattened"] is None and "not finite" in diverged["why"]
    assert convergence([1.0, None, 0.5, 0.4, 0.4, 0.4])["points"] == 5
    with pytest.raises(ValueError, match="tolerance"):
        convergence([1.0] * 5, tolerance=-0.1)
