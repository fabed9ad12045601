"""Model-order selection from the DSRA projection (Sec. II B of the paper: singular values, or
information criteria of Akaike, Bayes and Rissanen)."""

from __future__ import annotations

import numpy as np

from .realization import Projection, ShiftBasis, realize

ORDER_METHODS = ("gap", "aic", "bic", "mdl")


def max_order(proj: Projection) -> int:
    """Largest realizable order: the shifted observability matrix needs full column rank."""
    return proj.layout.l * (proj.layout.i - 1)


def select_order(proj: Projection, method: str = "gap", n_max: int | None = None) -> int:
    """Model order in [1, n_max].

    * ``gap``: the largest ratio of consecutive singular values s_n / s_{n+1};
    * ``aic`` / ``bic``: N log det(R_n) + penalty k(n) with R_n the (A4) output-residual
      covariance of the order-n realization, k(n) = n (2 l + m) + l m free parameters, penalty 2
      (AIC) or ln N (BIC), N the (effective) number of columns;
    * ``mdl``: Rissanen's minimum description length for the number of principal components of
      the projection (Wax-Kailath form on the squared singular values).
    """
    if method not in ORDER_METHODS:
        raise ValueError(f"order_method must be one of {ORDER_METHODS}, got {method!r}")
    top = max_order(proj) if n_max is None else min(n_max, max_order(proj))
    top = max(top, 1)
    s = proj.s[: top + 1]
    if method == "gap":
        if s.size < 2:
            return 1
        ratios = np.log(np.maximum(s[:-1], 1e-300)) - np.log(np.maximum(s[1:], 1e-300))
        return int(np.argmax(ratios[:top]) + 1)
    n_eff = max(proj.sum_w, 2.0)
    if method == "mdl":
        ev = np.maximum(proj.s**2, 1e-300)
        p = ev.size
        best, best_n = np.inf, 1
        for n in range(1, min(top, p - 1) + 1):
            tail = ev[n:]
            ratio = np.exp(np.mean(np.log(tail))) / np.mean(tail)
            crit = -n_eff * (p - n) * np.log(ratio) + 0.5 * n * (2 * p - n) * np.log(n_eff)
            if crit < best:
                best, best_n = crit, n
        return best_n
    lay = proj.layout
    pen = 2.0 if method == "aic" else np.log(n_eff)
    best, best_n = np.inf, 1
    basis = ShiftBasis(proj, top)
    for n in range(1, top + 1):
        r = realize(proj, n, basis).R
        sign, logdet = np.linalg.slogdet(r)
        if sign <= 0:
            continue
        crit = n_eff * logdet + pen * (n * (2 * lay.l + lay.m) + lay.l * lay.m)
        if crit < best:
            best, best_n = crit, n
    return best_n
