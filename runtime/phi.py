"""Cost factors Φ(d, d') for comparing a model with a more general one (report §5, app. B).

A more general model ``M'`` (d' degrees of freedom) replaces ``M`` (d) iff
``L̃'²/d' < Φ(d, d') · L̃²/d``. Choices, as declared in specs: a positive number (constant Φ,
default 1), ``"aic"`` (``d/d'``, eq. 50), ``"exp:κ"`` (``exp(−κ (d'−d)/d')``) and the F-test
factor ``"ftest"`` / ``"ftest:P"`` (default P = 0.95)::

    Φ_P(d, d') = (d/d') / (1 + F⁻¹_{d, d'−d}(P) · (d'−d)/d)

computed from the F distribution, never from the report's fitted κ values. A callable
``f(d, d_general) -> float`` is accepted too.
"""

from __future__ import annotations

import math
from collections.abc import Callable

Phi = Callable[[int, int], float]
DEFAULT_CONFIDENCE = 0.95


def constant(value: float) -> Phi:
    return lambda d, d_general: float(value)


def aic(d: int, d_general: int) -> float:
    """``d/d'`` (report eq. 50)."""
    return d / d_general


def exponential(kappa: float) -> Phi:
    """``exp(−κ (d'−d)/d')`` (report eq. 54's form)."""
    return lambda d, d_general: math.exp(-kappa * (d_general - d) / d_general)


def ftest(confidence: float = DEFAULT_CONFIDENCE) -> Phi:
    """The F-test factor at confidence ``P`` (report appendix B, SPEC §4).

    Examples
    --------
    >>> round(ftest(0.5)(1, 2), 2)   # the first entry of the report's P = 0.5 table
    0.25
    """

    def phi(d: int, d_general: int) -> float:
        extra = d_general - d
        if extra <= 0 or d <= 0:
            return 1.0
        from scipy import stats  # on first use: importing scipy.stats costs half a second

        quantile = stats.f.ppf(confidence, d, extra)  # fratio[d, d'−d], the report's Maple
        return float((d / d_general) / (1.0 + quantile * extra / d))

    return phi


def _number(text: str, choice) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"cost factor {choice!r}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise ValueError(f"cost factor {choice!r}: {text!r} is not finite")
    return value


def phi(choice: float | str | Phi) -> Phi:
    """The Φ function for a spec's or a user's choice."""
    if callable(choice):
        return choice
    if isinstance(choice, int | float) and not isinstance(choice, bool):
        if not 0 < choice < math.inf:
            raise ValueError(f"a constant Φ must be positive and finite, got {choice}")
        return constant(choice)
    word, _, arg = str(choice).partition(":")
    if word == "aic" and not arg:
        return aic
    if word == "ftest":
        confidence = _number(arg, choice) if arg else DEFAULT_CONFIDENCE
        if not 0.0 < confidence < 1.0:
            raise ValueError(f"the confidence P of {choice!r} must be in (0, 1)")
        return ftest(confidence)
    if word == "exp" and arg:
        return exponential(_number(arg, choice))
    raise ValueError(f"unknown cost factor {choice!r} (a number, 'aic', 'ftest', 'ftest:P', "
                     "'exp:kappa' or a callable f(d, d_general))")
