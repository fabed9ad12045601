"""What sysid_node says in /diagnostics, and the health it adds to its estimates (pure).

:func:`node_health` turns the node's own view (worker alive, reporting, backlog) into
``(level, reason)`` pairs of ``sysid_msgs/ModalEstimate`` HEALTH_* levels; :func:`merge_health`
folds them into a record's health (worst level wins); :func:`summary` chooses the
diagnostic level and message from the key-values.
"""

from __future__ import annotations

import math
from typing import Any

HEALTH_OK, HEALTH_DEGRADED, HEALTH_FAULT = 0, 1, 2
HEALTH_NAMES = {HEALTH_OK: "ok", HEALTH_DEGRADED: "degraded", HEALTH_FAULT: "fault"}
#: diagnostic_msgs/DiagnosticStatus levels
OK, WARN, ERROR, STALE = 0, 1, 2, 3
BAD_INPUT_KEYS = (
    "malformed", "wrong_channels", "nonfinite", "duplicate", "late", "rate_rejected",
    "unreadable", "shed", "bad_stamp", "channel_names_changed",
)


def merge_health(level: int, reason: str, faults: list[tuple[int, str]]) -> tuple[int, str]:
    """Worst level of ``level`` and ``faults``; the reasons of every level above OK, joined."""
    reasons = [reason] if reason and level > HEALTH_OK else []
    for lv, why in faults:
        if lv > HEALTH_OK and why and why not in reasons:
            reasons.append(why)
        level = max(level, lv)
    return level, "; ".join(reasons)


def node_health(alive: bool, stalled_s: float, backlog_s: float,
                backlog_warning: float, stall_limit: float) -> list[tuple[int, str]]:
    """The node's own faults: a dead or stalled worker (FAULT), a backlog above the warning
    level (DEGRADED). Only :func:`estimate_faults` of them go into the estimates."""
    out: list[tuple[int, str]] = []
    if not alive:
        out.append((HEALTH_FAULT, "estimator process not running (restarting)"))
    elif stalled_s > stall_limit:
        out.append((HEALTH_FAULT, f"estimator has not reported for {stalled_s:.1f} s"))
    if math.isfinite(backlog_s) and backlog_warning > 0 and backlog_s > backlog_warning:
        out.append((HEALTH_DEGRADED, f"estimator {backlog_s:.2f} s behind real time"))
    return out


def estimate_faults(faults: list[tuple[int, str]]) -> list[tuple[int, str]]:
    """The node faults an estimate carries: the FAULTs (no estimator), not the backlog. A late
    estimate is still the estimate of its data; its lateness is in its stamp, which the
    consumer judges against its own timeouts (notch_filter_node's stale_timeout): marking it
    degraded as well made the notches hold on every scheduling hiccup of a busy machine."""
    return [(lv, why) for lv, why in faults if lv >= HEALTH_FAULT]


def is_bad_input(key: str) -> bool:
    return key.endswith(BAD_INPUT_KEYS) or key in ("gaps", "time_resets")


def summary(kv: dict[str, Any], bad_new: int, stale: bool, converged: bool,
            faults: list[tuple[int, str]]) -> tuple[int, str]:
    """Diagnostic level and one-line message."""
    if stale:
        return STALE, "no data received"
    worst = max((lv for lv, _ in faults), default=HEALTH_OK)
    text = "; ".join(r for lv, r in faults if lv > HEALTH_OK)
    if worst >= HEALTH_FAULT:
        return ERROR, text
    if worst == HEALTH_DEGRADED:
        return WARN, text
    if bad_new > 0:
        return WARN, f"{bad_new} bad input event(s)"
    if not converged:
        return WARN, "not converged yet"
    return OK, "tracking"


def fmt(v: Any) -> str:
    """A diagnostic value as text (booleans lower case, floats to 6 digits, NaN as 'nan')."""
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.6g}"
    return str(v)
