"""Whether a loss had flattened (:func:`evaluators.metrics.convergence.convergence`), on
curves whose answer is known in closed form."""

from __future__ import annotations

import math

import pytest

from evaluators.metrics.convergence import convergence


def test01_exponential_decay_flattens_only_late() -> None:
    # loss = exp(-t / 10) over 100 points: windows of 10, the last one ~ e^-1 below the one
    # before; over 1000 points (t up to 100) the tail is flat to machine noise.
    short = convergence([math.exp(-t / 10) for t in range(100)])
    assert short["flattened"] is False
    assert short["relative_drop"] == pytest.approx(1 - math.exp(-1.0), rel=1e-9)
    assert "fell" in short["why"]
    plateau = convergence([1.0 + math.exp(-t / 10) for t in range(1000)])
    assert plateau["flattened"] is True and plateau["relative_drop"] < 1e-3


def test02_rising_and_constant_and_tolerance() -> None:
    rising = convergence([1.0] * 18 + [2.0, 2.0])
    assert rising["flattened"] is False and rising["relative_drop"] == pytest.approx(-1.0)
    assert "rose" in rising["why"]
    assert convergence([0.5] * 10)["flattened"] is True
    # a 3 % drop over the last tenth: flat at 5 %, not at 2 %
    curve = [1.0] * 18 + [0.97] * 2  # windows of 2 points
    assert convergence(curve, tolerance=0.05)["flattened"] is True
    assert convergence(curve, tolerance=0.02)["flattened"] is False


def test03_no_verdict() -> None:
    assert convergence([1.0, 0.5, 0.2])["flattened"] is None
    assert convergence([])["flattened"] is None
    diverged = convergence([1.0, 0.5, 0.2, 0.1, float("nan")])
    assert diverged["flattened"] is None and "not finite" in diverged["why"]
    assert convergence([1.0, None, 0.5, 0.4, 0.4, 0.4])["points"] == 5
    with pytest.raises(ValueError, match="tolerance"):
        convergence([1.0] * 5, tolerance=-0.1)
