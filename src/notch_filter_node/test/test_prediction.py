"""Bank state PREDICTED: while the identification is degraded (e.g. starved of excitation),
unconverged or late, the notches follow the modes an LPV model predicts from the scheduling
signal, handed over from (and back to) the identified modes without fading out and in."""

import math

from notch_filter_node.policy import EstimateInput, ModeInput, PolicyConfig

from notch_filter_node import policy as P

FS = 200.0
CFG = PolicyConfig(fallback_depth=30.0, stale_timeout=1.0, fallback_timeout=10.0)


def identified(t, f, health=P.HEALTH_OK, predicted=None, converged=True):
    modes = [ModeInput(7, "tracked", f, 0.01, 0.01, 0.002)]
    pred = [] if predicted is None else [ModeInput(2, "tracked", predicted, 0.02, 0.01, 0.002)]
    reason = "" if health == P.HEALTH_OK else "excitation starved"
    return EstimateInput(t, converged, modes, health, reason, t, pred)


def run(pol, t0, t1, make, dt=0.1):
    """Estimates from ``make(t)`` every dt, the policy advanced in between; notch log (one
    entry per notch, single or pair: its mode, state, centre and depth of presence)."""
    log = []
    t = t0
    while t < t1 - 1e-9:
        e = make(t)
        if e is not None:
            pol.set_estimate(e)
        pol.advance(t + dt, dt)
        t += dt
        log.append((t, pol.bank_state, [(s.mode_id, s.state, s.center, s.depth)  # per notch
                                         for s in pol.slots if s.depth > 0
                                         or s.state != P.DISABLED]))
    return log


def test_degraded_identification_hands_over_to_the_prediction_and_back():
    pol = P.RetuningPolicy(CFG, FS)
    run(pol, 0.0, 3.0, lambda t: identified(t, 30.0, predicted=30.02))
    assert pol.bank_state == P.BANK_TRACKING
    slot = next(s for s in pol.slots[:-1] if s.mode_id == 7)
    # starved: the estimate is degraded (and its mode lags); the prediction moves 30 -> 31 Hz
    log = run(pol, 3.0, 8.0, lambda t: identified(t, 30.0, P.HEALTH_DEGRADED,
                                                   predicted=30.0 + 0.2 * (t - 3.0)))
    assert pol.bank_state == P.BANK_PREDICTED and "LPV prediction" in pol.reason
    assert slot.mode_id == P.PREDICTED_ID_BASE + 2 and slot.state == P.PREDICTED  # handed over
    # the notch is never faded out in the handover and follows the prediction (slew 1 Hz/s)
    depths = [max((d for (_, st, _, d) in ns if st in (P.TRACKING, P.PREDICTED)), default=0.0)
              for _, _, ns in log]
    assert min(depths) >= CFG.depth - 1e-9
    assert abs(slot.center - (30.0 + 0.2 * 4.9)) < 0.05
    assert not pol.fallback_active
    # identification good again: back to TRACKING, the same section takes the identified mode
    run(pol, 8.0, 9.0, lambda t: identified(t, 31.0, predicted=31.0))
    assert pol.bank_state == P.BANK_TRACKING and slot.mode_id == 7 and slot.state == P.TRACKING


def test_without_prediction_the_bank_holds_then_falls_back():
    pol = P.RetuningPolicy(CFG, FS)
    run(pol, 0.0, 3.0, lambda t: identified(t, 30.0))
    run(pol, 3.0, 4.0, lambda t: identified(t, 30.0, P.HEALTH_DEGRADED))
    assert pol.bank_state == P.BANK_HOLDING


def test_stale_prediction_is_not_followed():
    """Estimates (and with them the predictions) stop: the prediction ages like the estimate,
    and the bank holds, then falls back, as without one."""
    pol = P.RetuningPolicy(CFG, FS)
    run(pol, 0.0, 3.0, lambda t: identified(t, 30.0, P.HEALTH_DEGRADED, predicted=30.0,
                                            converged=False))
    assert pol.bank_state == P.BANK_PREDICTED  # never converged: the prediction serves
    run(pol, 3.0, 4.5, lambda t: None)
    assert pol.bank_state in (P.BANK_HOLDING, P.BANK_FALLBACK)
    run(pol, 4.5, 16.0, lambda t: None)
    assert pol.bank_state == P.BANK_FALLBACK and pol.fallback_active
    assert math.isnan(pol.age()) or pol.age() > CFG.fallback_timeout
