"""Retuning policy: tracked-only notches, slew and hysteresis, bandwidth from uncertainty within
the phase-lag budget, hold-then-fade of lost modes, fallback on stale or unconverged estimates,
and retuning without transients."""

import numpy as np
import pytest
from notch_filter_node.adaptive import AdaptiveNotchFilter
from notch_filter_node.policy import EstimateInput, ModeInput, PolicyConfig
from scipy import signal

from notch_filter_node import policy as P
from notch_filter_node import sections as S

FS = 200.0


def est(t, f, status="tracked", std=0.005, mid=1, converged=True, zeta=0.02):
    return EstimateInput(t, converged, [ModeInput(mid, status, f, std, zeta, 0.002)])


def sine(f, seconds, fs=FS):
    t = np.arange(int(seconds * fs)) / fs
    return np.sin(2 * np.pi * f * t)[:, None]


def test_tentative_mode_gets_no_notch_tracked_one_does():
    pol = P.RetuningPolicy(PolicyConfig(fallback_depth=0.0), FS)
    pol.set_estimate(est(0.0, 3.0, status="tentative"))
    pol.advance(0.1, 0.1)
    assert pol.status().notches == []
    pol.set_estimate(est(0.2, 3.0))
    pol.advance(0.3, 0.1)
    (n,) = pol.status().notches
    assert (n.mode_id, n.state, n.center) == (1, P.TRACKING, 3.0)
    assert 0 < n.depth < 30.0  # fades in, never at once


def test_out_of_band_mode_is_not_notched():
    pol = P.RetuningPolicy(PolicyConfig(freq_min=2.0, fallback_depth=0.0), FS)
    pol.set_estimate(EstimateInput(0.0, True, [ModeInput(1, "tracked", 1.0, 0.01)]))
    pol.advance(0.5, 0.5)
    assert pol.status().notches == []


def test_slew_rate_and_hysteresis():
    cfg = PolicyConfig(slew_rate=0.5, hysteresis=0.02, hysteresis_sigma=0.0, fallback_depth=0.0,
                       stale_timeout=100.0)
    pol = P.RetuningPolicy(cfg, FS)
    pol.set_estimate(est(0.0, 3.0))
    pol.advance(0.0, 0.0)
    pol.set_estimate(est(0.1, 3.015))  # within the hysteresis: target stays
    pol.advance(0.2, 0.2)
    assert pol.slots[0].center == 3.0
    pol.set_estimate(est(0.3, 3.5))
    centres = []
    for k in range(1, 21):
        pol.advance(0.3 + 0.1 * k, 0.1)
        centres.append(pol.slots[0].center)
    steps = np.diff([3.0, *centres])
    assert np.max(steps) == pytest.approx(0.05)  # 0.5 Hz/s over 0.1 s
    assert centres[-1] == pytest.approx(3.5)


def test_confident_estimate_gets_narrower_notch_and_keeps_attenuation():
    cfg = PolicyConfig(fallback_depth=0.0, phase_lag_budget=90.0)
    widths = []
    for std in (0.002, 0.01, 0.05):
        pol = P.RetuningPolicy(cfg, FS)
        pol.set_estimate(est(0.0, 3.0, std=std, zeta=0.0))
        pol.advance(0.0, 0.0)
        s = pol.slots[0]
        widths.append(s.bandwidth)
        half = cfg.sigma_k * std + max(cfg.hysteresis, cfg.hysteresis_sigma * std)
        sos = S.notch_sos(3.0, s.bandwidth, cfg.depth, FS)
        att = -20 * np.log10(np.abs(S.response(sos, [3.0 - half, 3.0 + half], FS)))
        assert att.min() == pytest.approx(cfg.min_attenuation, abs=0.05)
    assert widths[0] < widths[1] < widths[2]


def test_phase_lag_budget_narrows_the_notches():
    cfg = PolicyConfig(fallback_depth=0.0, phase_lag_budget=1.0, bandwidth_min=0.02)
    pol = P.RetuningPolicy(cfg, FS)
    modes = [ModeInput(1, "tracked", 2.2, 0.05, 0.02), ModeInput(2, "tracked", 4.0, 0.05, 0.02)]
    pol.set_estimate(EstimateInput(0.0, True, modes))
    st = pol.status()
    assert st.budget_limited
    t = [s for s in pol.slots if s.state == P.TRACKING]
    sos = S.notch_sos([s.target_center for s in t], [s.target_bandwidth for s in t],
                      [cfg.depth] * 2, FS)
    assert S.phase_lag_deg(sos, cfg.crossover_frequency, FS) == pytest.approx(1.0, abs=1e-3)
    assert all(s.target_bandwidth < s.desired_bandwidth for s in t)


def test_new_notch_starts_within_the_budget():
    """An uncertain first estimate wants a wide notch: it starts at the budget-limited width
    (its depth is still 0), not at the wide one narrowed later at the slew rate."""
    cfg = PolicyConfig(phase_lag_budget=2.0, fallback_depth=0.0)
    pol = P.RetuningPolicy(cfg, FS)
    pol.set_estimate(est(0.0, 3.0, std=0.2))
    (slot,) = [s for s in pol.slots[:-1] if s.state == P.TRACKING]
    assert slot.bandwidth == slot.target_bandwidth < slot.desired_bandwidth
    pol.advance(1.5, 1.5)  # faded in
    assert S.phase_lag_deg(S.notch_sos(3.0, slot.bandwidth, cfg.depth, FS), 0.5, FS) <= 2.0 + 1e-6


@pytest.mark.parametrize(("floor", "notched"), [(0.05, [1]), (0.0, [1, 2])])
def test_small_modes_get_no_notch(floor, notched):
    cfg = PolicyConfig(min_relative_amplitude=floor, fallback_depth=0.0)
    pol = P.RetuningPolicy(cfg, FS)
    modes = [ModeInput(1, "tracked", 3.0, 0.005, 0.02, 0.002, amplitude=1.0),
             ModeInput(2, "tracked", 7.4, 0.3, 0.05, 0.01, amplitude=0.01)]  # 1 %: noise mode
    pol.set_estimate(EstimateInput(0.0, True, modes))
    pol.advance(0.5, 0.5)
    assert sorted(n.mode_id for n in pol.status().notches) == notched


@pytest.mark.parametrize("block", [1, 10, 64])
def test_retuning_under_a_sine_gives_no_transient(runner, block):
    """A sine at the mode frequency passes while the notch retunes 2.9 <-> 3.0 Hz: the output
    never exceeds the larger filtered steady state (2 % margin); a bank that switches its
    coefficients at once with its transposed-direct-form state exceeds it by far."""
    x = sine(3.0, 20.0)
    cfg = PolicyConfig(slew_rate=0.5, stale_timeout=100.0, fallback_depth=0.0)
    for f_from, f_to in ((2.9, 3.0), (3.0, 2.9)):
        flt = AdaptiveNotchFilter(cfg, FS, 1)
        (y,) = runner.run([flt], [x], FS, block,
                          [(0.0, est(0.0, f_from)), (10.0, est(10.0, f_to))])
        before = np.max(np.abs(y[int(6 * FS) : int(10 * FS)]))
        after = np.max(np.abs(y[int(16 * FS) :]))
        during = np.max(np.abs(y[int(10 * FS) :]))
        assert flt.status().notches[0].center == pytest.approx(f_to)
        assert during <= 1.02 * max(before, after), (f_from, f_to, before, after, during)
    # the same check catches a bank that restarts its sections on a retune (fresh state)
    sos1, sos2 = S.notch_sos(2.9, 0.3, 30.0, FS), S.notch_sos(3.0, 0.3, 30.0, FS)
    n = int(10 * FS)
    y1 = signal.sosfilt(sos1, x[:n, 0])
    y2 = signal.sosfilt(sos2, x[n:, 0])
    before, after = np.max(np.abs(y1[int(6 * FS) :])), np.max(np.abs(y2[-int(2 * FS) :]))
    assert np.max(np.abs(y2)) > 1.1 * max(before, after)


def test_lost_mode_holds_then_fades_without_step(runner):
    cfg = PolicyConfig(hold_time=1.0, fade_time=1.0, stale_timeout=100.0, fallback_depth=0.0)
    flt = AdaptiveNotchFilter(cfg, FS, 1)
    x = sine(3.0, 8.0)
    depth = []
    ests = [(t, est(t, 3.0)) for t in np.arange(0.0, 3.01, 0.2)]
    ests += [(t, est(t, 3.0, status="lost")) for t in np.arange(3.2, 8.0, 0.2)]
    (y,) = runner.run([flt], [x], FS, 10, ests,
                      on_block=lambda t: depth.append((t, flt.policy.slots[0].depth,
                                                       flt.policy.slots[0].state)))
    t, d, s = (np.array(v) for v in zip(*depth, strict=True))
    assert np.all(d[(t > 2.0) & (t < 4.2)] == 30.0)  # held for hold_time after the loss at 3.2
    fading = (t > 4.3) & (t < 5.1)
    assert np.all((d[fading] > 0) & (d[fading] < 30.0))
    assert np.all(np.diff(d[t > 3.0]) <= 0)
    assert s[-1] == P.DISABLED and flt.status().notches == []
    # no step: the output changes per sample no faster than the input sine itself does
    dx = np.max(np.abs(np.diff(x[:, 0])))
    assert np.max(np.abs(np.diff(y[:, 0]))) <= 1.01 * dx
    assert np.max(np.abs(y[int(3 * FS) : int(4 * FS), 0])) < 0.1  # notched before the fade
    np.testing.assert_allclose(np.max(np.abs(y[-int(FS) :, 0])), 1.0, atol=0.05)


@pytest.mark.parametrize("how", ["stop", "unconverged"])
def test_stale_or_unconverged_estimates_fall_back_within_timeout(runner, how):
    cfg = PolicyConfig(stale_timeout=1.0, fallback_ramp=0.25, fallback_center=2.8,
                       fallback_bandwidth=4.0, fallback_depth=30.0)
    flt = AdaptiveNotchFilter(cfg, FS, 1)
    ests = [(t, est(t, 3.0)) for t in np.arange(0.0, 3.01, 0.2)]
    if how == "unconverged":
        ests += [(t, est(t, 3.0, converged=False)) for t in np.arange(3.2, 6.0, 0.2)]
    log = []
    runner.run([flt], [sine(1.0, 6.0)], FS, 5, ests,
               on_block=lambda t: log.append((t, flt.status().fallback_active,
                                              flt.policy.slots[-1].depth)))
    t, active, fb_depth = (np.array(v) for v in zip(*log, strict=True))
    assert not active[(t > 0.5) & (t < 3.0)].any()
    assert np.all(fb_depth[(t > 1.5) & (t < 3.0)] == 0.0)
    # the last good estimate is stamped 3.0 s: full fallback depth by 3.0 + stale_timeout
    t_full = t[(t > 3.0) & (fb_depth >= 30.0 - 1e-9)][0]
    assert t_full <= 3.0 + cfg.stale_timeout + 5 / FS
    assert active[t > 4.0].all()
    if how == "stop":
        assert t[(t > 3.0) & active][0] >= 3.0 + cfg.stale_timeout - cfg.fallback_ramp - 1e-9
    (n_fb,) = [n for n in flt.status().notches if n.state == P.PARKED]
    assert (n_fb.center, n_fb.bandwidth, n_fb.depth) == (2.8, 4.0, 30.0)


def test_no_estimate_at_start_means_fallback_at_full_depth():
    pol = P.RetuningPolicy(PolicyConfig(), FS)
    pol.advance(0.01, 0.01)
    st = pol.status()
    assert st.fallback_active and st.notches[0].state == P.PARKED
    assert st.notches[0].depth == PolicyConfig().depth


def test_check_config_reasons():
    assert P.check_config(PolicyConfig()) == ""
    assert "must exceed" in P.check_config(PolicyConfig(depth=20.0, min_attenuation=20.0))
    assert "freq_min" in P.check_config(PolicyConfig(freq_min=5.0, freq_max=4.0))
    assert "Nyquist" in P.check_config(PolicyConfig(freq_max=150.0), fs=200.0)
    assert "fallback_ramp" in P.check_config(PolicyConfig(fallback_ramp=2.0))


def test_disabled_channel_passes_through(runner):
    flt = AdaptiveNotchFilter(PolicyConfig(stale_timeout=100.0), FS, 2)
    flt.enabled = np.array([True, False])
    x = np.repeat(sine(3.0, 4.0), 2, axis=1)
    (y,) = runner.run([flt], [x], FS, 10, [(0.0, est(0.0, 3.0))])
    np.testing.assert_array_equal(y[:, 1], x[:, 1])
    assert np.max(np.abs(y[-int(FS) :, 0])) < 0.1


def test_live_reconfigure_moves_depth_at_the_fade_rate():
    pol = P.RetuningPolicy(PolicyConfig(stale_timeout=100.0, fade_time=1.0), FS)
    pol.set_estimate(est(0.0, 3.0))
    for k in range(30):
        pol.advance(0.1 * k, 0.1)
    assert pol.slots[0].depth == 30.0
    pol.reconfigure(P.with_changes(pol.config, depth=40.0))
    pol.advance(3.1, 0.1)
    assert pol.slots[0].depth == pytest.approx(34.0)  # 40 dB / 1 s over 0.1 s
    with pytest.raises(ValueError, match="max_notches"):
        pol.reconfigure(P.with_changes(pol.config, max_notches=2))


def test_full_bank_keeps_its_modes_and_takes_the_largest_new_ones():
    cfg = PolicyConfig(max_notches=2, fallback_depth=0.0, stale_timeout=100.0, damping_max=0.1)
    pol = P.RetuningPolicy(cfg, FS)

    def mode(i, f, amp, zeta=0.02):
        return ModeInput(i, "tracked", f, 0.01, zeta, 0.002, amp)

    pol.set_estimate(EstimateInput(0.0, True, [mode(1, 3.0, 1.0), mode(2, 5.0, 2.0),
                                               mode(3, 7.0, 5.0, zeta=0.3)]))
    assert sorted(s.mode_id for s in pol.slots[:-1] if s.state == P.TRACKING) == [1, 2]
    pol.set_estimate(EstimateInput(0.1, True, [mode(1, 3.0, 1.0), mode(2, 5.0, 2.0),
                                               mode(4, 9.0, 9.0)]))
    assert sorted(s.mode_id for s in pol.slots[:-1] if s.state == P.TRACKING) == [1, 2]
    pol = P.RetuningPolicy(cfg, FS)
    pol.set_estimate(EstimateInput(0.0, True, [mode(1, 3.0, 1.0), mode(2, 5.0, 2.0),
                                               mode(4, 9.0, 9.0)]))
    assert sorted(s.mode_id for s in pol.slots[:-1] if s.state == P.TRACKING) == [2, 4]


def test_out_of_order_estimate_ignored_restart_accepted():
    pol = P.RetuningPolicy(PolicyConfig(stale_timeout=2.0, fallback_depth=0.0), FS)
    pol.set_estimate(est(10.0, 3.0))
    pol.set_estimate(est(9.9, 4.0))  # late arrival
    assert pol.estimate.stamp == 10.0
    pol.set_estimate(est(1.0, 4.0))  # the estimator restarted
    assert pol.estimate.stamp == 1.0
