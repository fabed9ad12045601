"""The per-call fast path of RecursiveDSRA (shared innovation product of the outlier gate and
the change statistics, closed-form exponential means, cached weights) gives the numbers of the
straightforward implementation: ``ReferenceDSRA`` below is the update path as it was before
the optimisation (one product per statistic, lfilter, weights recomputed per call). Both are
fed the same seeded records, with spikes, NaN rows and an abrupt change, in irregular blocks;
the gate decisions, the change cuts (where the information is discounted), the information
matrix and every realized model's modes must agree up to rounding."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import butter, lfilter, sosfilt, sosfilt_zi
from sysid_node.core import RecursiveDSRA
from sysid_node.core.hankel import window_rows_packed
from sysid_node.core.lti import simulate, simulate_with_state
from sysid_node.core.recursive import (
    DETECTION_BAND_MARGIN,
    GATE_REFERENCE_FLOOR,
    GATE_REFERENCE_WINDOWS,
    GATE_WILD_FACTOR,
    INPUT_RECENT_WINDOWS,
    SPLIT_FILTER_ORDER,
    SPLIT_NYQUIST_FRACTION,
)
from sysid_node.scenarios.excitations import white
from sysid_node.scenarios.noise import add_output_noise
from sysid_node.scenarios.paper import paper_example_data
from sysid_node.scenarios.structures import modal_system


class ReferenceDSRA(RecursiveDSRA):
    """RecursiveDSRA with the straightforward update path (gate, change statistics split at
    the band top in every block, RLS)."""

    def reset(self):
        super().reset()
        self._ref_split = None  # (filter states, short, long) of the band split

    def _ref_in_band(self, e):
        """(n, l) in-band rises of the a-priori errors e of one block, the split run on it."""
        l = self.n_outputs
        nyq = 0.5 * self.fs
        if self.band is None or self.band[1] >= SPLIT_NYQUIST_FRACTION * nyq:
            return np.ones(e.shape, dtype=bool)
        sos = [butter(SPLIT_FILTER_ORDER, self.band[1] / nyq, kind, output="sos")
               for kind in ("low", "high")]
        if self._ref_split is None:
            zi = [sosfilt_zi(s)[:, :, None] * e[0] for s in sos]
            self._ref_split = (zi, np.full(2 * l, np.nan), np.full(2 * l, np.nan))
        zi, short0, long0 = self._ref_split
        parts, zf = [], []
        for s, z in zip(sos, zi, strict=True):
            part, z = sosfilt(s, e, axis=0, zi=z)
            parts.append(part**2)
            zf.append(z)
        sq = np.hstack(parts)
        short = self._ref_ew_path(short0, sq, 1.0 - 1.0 / self.change_window)
        long_ = self._ref_ew_path(long0, sq, self.forgetting_factor)
        before = np.vstack([long0, long_[:-1]])
        self._ref_split = (zf, short[-1], long_[-1])
        ratio_in = short[:, :l] * before[:, l:]
        ratio_above = short[:, l:] * before[:, :l]
        return ratio_in >= DETECTION_BAND_MARGIN * ratio_above

    def _accumulate(self, data):
        bad = self._ref_gate(data) if self.outlier_gate else None
        if bad is None or not bad.any():
            self._ref_accumulate_clean(data)
            return
        start = 0
        for b in np.flatnonzero(bad):
            if b > start:
                self._ref_accumulate_clean(data[start:b])
            self._tail = self._tail[:0]
            start = b + 1
        if start < data.shape[0]:
            self._ref_accumulate_clean(data[start:])

    def _ref_gate(self, data):
        m, l, i = self.n_inputs, self.n_outputs, self.block_rows
        hist = np.vstack([self._gate_tail, data])
        n0 = self._gate_tail.shape[0]
        n = data.shape[0]
        bad = np.zeros(n, dtype=bool)
        ref = self._gate_ref
        q_y, q_u = self._gate_q
        k = 0
        e2_all = np.zeros((n, l))
        level = max(float(np.max(np.abs(data[:, m:]), initial=0.0)), 1.0)
        while k < n:
            pred = self._ref_gate_prediction(hist, n0 + k, level)
            e2 = (hist[n0 + k :, m:] - pred) ** 2
            e2_all[k:] = e2
            over = (e2 / ref[m:]).sum(axis=1) > q_y
            if m:
                over |= (hist[n0 + k :, :m] ** 2 / ref[:m]).sum(axis=1) > q_u
            hit = np.flatnonzero(over)
            if hit.size == 0:
                break
            j = k + int(hit[0])
            bad[j] = True
            hist[n0 + j, m:] = pred[hit[0]]
            if m:
                hist[n0 + j, :m] = 0.0
            k = j + 1
        good = np.hstack([hist[n0:, :m], e2_all])[~bad]
        good[:, :m] **= 2
        if good.shape[0]:
            lam = min(self.forgetting_factor,
                      1.0 - 1.0 / (GATE_REFERENCE_WINDOWS * self.change_window))
            w = lam ** np.arange(good.shape[0] - 1, -1, -1.0)
            self._gate_ref = lam ** good.shape[0] * ref + (1 - lam) * (w[:, None] * good).sum(0)
            self._gate_ref = np.maximum(self._gate_ref, GATE_REFERENCE_FLOOR)
        self._gate_tail = hist[-i:] if hist.shape[0] > i else hist
        if bad.any():
            self.outliers_rejected += int(bad.sum())
            self._last_outlier = self._gated + int(np.flatnonzero(bad)[-1])
        trailing = n - 1 - int(np.flatnonzero(~bad)[-1]) if (~bad).any() else n
        self._gate_run = self._gate_run + n if trailing == n else trailing
        self._gated += n
        if self._gate_run > GATE_REFERENCE_WINDOWS * self.change_window:
            self._restart_level()
            return np.ones(n, dtype=bool)
        return bad

    def _ref_gate_prediction(self, hist, start, level=1.0):
        m, l, i = self.n_inputs, self.n_outputs, self.block_rows
        rows = hist.shape[0] - start
        pred = np.zeros((rows, l))
        if self._theta1 is None or start + rows <= i:
            return pred
        first = max(start, i)
        past = np.lib.stride_tricks.sliding_window_view(hist[first - i : -1], i, axis=0)
        past = past[: hist.shape[0] - first]
        up = past[:, :m, :].transpose(0, 2, 1).reshape(past.shape[0], i * m)
        yp = past[:, m:, :].transpose(0, 2, 1).reshape(past.shape[0], i * l)
        th = self._theta1
        npast = i * (m + l)
        p = up @ th[:, : i * m].T + yp @ th[:, i * m : npast].T
        if m:
            p += hist[first:, :m] @ th[:, npast : npast + m].T
        wild = ~np.all(np.abs(p) <= GATE_WILD_FACTOR * level, axis=1)
        p[wild] = 0.0
        pred[first - start :] = p
        return pred

    def _ref_accumulate_clean(self, data):
        i = self.block_rows
        buf = np.vstack([self._tail, data])
        self._tail = buf[-(2 * i - 1) :]
        z = window_rows_packed(buf, self.n_inputs, i)
        if z.shape[0] == 0:
            return
        start = 0
        for cut in self._ref_change_cuts(z):
            self._ref_add_windows(z[start:cut])
            self._discount(self.change_discount)
            start = cut
        self._ref_add_windows(z[start:])

    @staticmethod
    def _ref_ew_path(prev, sq, lam):
        p0 = np.where(np.isfinite(prev), prev, sq[0])
        return lfilter([1.0 - lam], [1.0, -lam], sq, axis=0, zi=lam * p0[None, :])[0]

    def _ref_change_cuts(self, z):
        if self._theta1 is None:
            return []
        lay = self.layout
        r = self._theta1.shape[1]
        yf1 = z[:, lay.yf.start : lay.yf.start + self.n_outputs]
        e = yf1 - z[:, :r] @ self._theta1.T
        e2 = e**2
        in_band = self._ref_in_band(e)
        cuts = []
        pos, n = 0, e2.shape[0]
        while pos < n:
            seg = e2[pos:]
            short = self._ref_ew_path(self._pe_short, seg, 1.0 - 1.0 / self.change_window)
            long_ = self._ref_ew_path(self._pe_ms, seg, self.forgetting_factor)
            event = len(seg)
            free = max(self._holdoff - 1, 0)
            if self.change_detection and free < len(seg):
                limit = self.change_threshold * long_
                hit = (short[free + 1 :] > limit[free:-1]) & in_band[pos + free + 1 :]
                first = short[free] > self.change_threshold * (
                    self._pe_ms if free == 0 else long_[free - 1]
                )
                first &= in_band[pos + free]
                if first.any():
                    event = free
                elif hit.any():
                    event = free + 1 + int(np.argmax(hit.any(axis=1)))
            second = self._second_discount - 1 if self._second_discount > 0 else len(seg)
            if event < len(seg) and event <= second:
                self._holdoff = int(round(1.0 / max(1.0 - self.forgetting_factor, 1e-3)))
                self._second_discount = 2 * self.block_rows
                self._change_count += 1
            elif second < len(seg):
                event = second
                self._second_discount = 0
                self._holdoff = max(self._holdoff - (event + 1), 0)
            else:
                self._holdoff = max(self._holdoff - len(seg), 0)
                self._second_discount = max(self._second_discount - len(seg), 0)
            last = min(event, len(seg) - 1)
            self._pe_short, self._pe_ms = short[last], long_[last]
            if event < len(seg):
                cuts.append(pos + event)
            pos += last + 1
        return cuts

    def _ref_add_windows(self, z):
        n = z.shape[0]
        if n == 0:
            return
        lam_f = self.forgetting_factor
        memory = 1.0 / max(1.0 - lam_f, 1e-12)
        first, last = self._k + 1, self._k + n
        if not self.startup_memory or first >= memory:
            w = lam_f ** np.arange(n - 1, -1, -1.0)
            decay = lam_f**n
        elif last < memory:
            w, decay = np.ones(n), 1.0
        else:
            lam = np.where(np.arange(first, last + 1) < memory, 1.0, lam_f)
            w = np.append(np.cumprod(lam[::-1])[::-1][1:], 1.0)
            decay = float(np.prod(lam))
        info = self._info
        if decay != 1.0:
            info *= decay
            np.einsum("ii->i", info)[...] += self._ridge * (1.0 - decay)
        info += (z * w[:, None]).T @ z
        if self._u_cols.size and self.stabilize:
            lam_u = min(lam_f, 1.0 - 1.0 / (INPUT_RECENT_WINDOWS * 2 * self.layout.i))
            zu = z[:, self._u_cols]
            self._u_recent *= lam_u**n
            self._u_recent += (zu * (lam_u ** np.arange(n - 1, -1, -1.0))[:, None]).T @ zu
        self._sum_w = decay * self._sum_w + float(w.sum())
        self._sum_w2 = decay**2 * self._sum_w2 + float(w @ w)
        self._k += n


def _siso_record():
    """Paper Sec. II example (6 Hz mode appears at 8 s), spikes, a NaN and a 0.5 s burst."""
    _, u, y = paper_example_data(duration_s=16.0, fs=100.0, seed=3, switch_time_s=8.0)
    y, u = y.copy(), u.copy()
    y[450] *= 1e4
    y[460] = -3e5 * np.std(y)
    u[1000] = 1e5
    y[700] = np.nan
    y[1200:1250] *= 1e9  # a 0.5 s burst: rejected samples in a row
    return u, y, 100.0, {"block_rows": 20, "max_modes": 5, "forgetting_factor": 0.99,
                         "realization_interval": 5, "band": (0.0, 10.0)}


def _mimo_record():
    """1 input / 3 outputs at 500 Hz, 13 -> 9 Hz at 3 s, output and input spikes, a NaN input."""
    rng = np.random.default_rng(11)
    fs, n = 500.0, 3000
    shape = rng.normal(size=(3, 3))
    a = modal_system([5.0, 13.0, 31.0], [0.02, 0.02, 0.015], np.ones((3, 1)), shape,
                     output="velocity")
    b = modal_system([5.0, 9.0, 31.0], [0.02, 0.02, 0.015], np.ones((3, 1)), shape,
                     output="velocity")
    u = white(n, 1, rng)
    y = np.vstack([simulate(a, u[:1500], fs), simulate(b, u, fs)[1500:]])
    y = add_output_noise(y, 0.05, rng)
    y[900, 1] *= 1e5
    y[2500, 0] = 1e4 * np.std(y[:, 0])
    u[1800] = 1e4
    u[2100] = np.nan
    return u, y, fs, {"block_rows": 12, "max_modes": 3, "forgetting_factor": 0.998,
                      "realization_interval": 25, "band": (0.0, 60.0)}


def _trace(cls, record, blocks, **extra):
    u, y, fs, cfg = record
    est = cls(y.shape[1], u.shape[1], fs=fs, **cfg, **extra)
    cuts = []
    discount = est._discount

    def record_cut(c):
        cuts.append(est._k)
        discount(c)

    est._discount = record_cut
    models, gates, a = [], [], 0
    for b in blocks:
        models += est.update(u[a : a + b], y[a : a + b])
        gates.append((est.outliers_rejected, est._gated, est._last_outlier, est.level_restarts))
        a += b
    est.flush()
    return est, cuts, models, gates


@pytest.mark.parametrize("record", [_siso_record, _mimo_record], ids=["siso", "mimo"])
@pytest.mark.parametrize("blocking", ["single", "irregular"])
@pytest.mark.parametrize("stabilize", [False, True])
def test_fast_path_equals_reference(record, blocking, stabilize):
    rec = record()
    n = rec[1].shape[0]
    if blocking == "single":
        blocks = [1] * n
    else:
        sizes = np.random.default_rng(5).integers(1, 400, size=n)
        ends = np.cumsum(sizes)
        blocks = list(sizes[ends < n]) + [n - int(ends[ends < n][-1] if (ends < n).any() else 0)]
    fast, cuts_f, models_f, gates_f = _trace(RecursiveDSRA, rec, blocks, stabilize=stabilize)
    ref, cuts_r, models_r, gates_r = _trace(ReferenceDSRA, rec, blocks, stabilize=stabilize)
    # the records exercise what they should: rejected samples, detected changes, realizations
    assert ref.outliers_rejected >= 3 and ref._change_count >= 1 and len(models_r) > 20
    assert gates_f == gates_r  # same samples rejected, at the same calls
    assert cuts_f == cuts_r  # information discounted before the same windows
    assert fast._change_count == ref._change_count
    assert fast._samples_skipped == ref._samples_skipped == 1
    np.testing.assert_allclose(fast._gate_ref, ref._gate_ref, rtol=1e-9)
    np.testing.assert_allclose(fast._pe_ms, ref._pe_ms, rtol=1e-9)
    np.testing.assert_allclose(fast._pe_short, ref._pe_short, rtol=1e-9)
    scale = np.abs(ref._info).max()
    np.testing.assert_allclose(fast._info, ref._info, rtol=0, atol=1e-10 * scale)
    assert [mf.time_s for mf in models_f] == [mr.time_s for mr in models_r]
    for mf, mr in zip(models_f, models_r, strict=True):
        ff = np.sort([md.frequency_hz for md in mf.modes])
        fr = np.sort([md.frequency_hz for md in mr.modes])
        assert ff.shape == fr.shape
        np.testing.assert_allclose(ff, fr, rtol=1e-6, atol=1e-9)
    final_f = sorted((md.frequency_hz, md.damping_ratio) for md in fast.modes())
    final_r = sorted((md.frequency_hz, md.damping_ratio) for md in ref.modes())
    np.testing.assert_allclose(final_f, final_r, rtol=1e-6, atol=1e-9)


def _above_band_record():
    """1 input / 2 outputs at 100 Hz, band 0-10 Hz (split at its top): a 30 -> 35 Hz jump above
    the band at 10 s (the unsplit statistic rises, the split vetoes it), a 6 -> 7.5 Hz jump
    inside it at 20 s (a change), 5 % noise, a spike."""
    rng = np.random.default_rng(1)
    fs, n = 100.0, 3000
    shape = rng.normal(size=(2, 3))
    systems = [modal_system([4.0, f_in, f_above], [0.02, 0.02, 0.02], np.ones((3, 1)), shape,
                            output="velocity") for f_in, f_above in ((6, 30), (6, 35), (7.5, 35))]
    u = white(n, 1, rng)
    parts, x = [], None
    for k, system in enumerate(systems):
        y, x = simulate_with_state(system, u[k * 1000 : (k + 1) * 1000], fs, x0=x)
        parts.append(y)
    y = add_output_noise(np.vstack(parts), 0.05, rng)
    y[500, 0] *= 1e5
    return u, y, fs, {"block_rows": 10, "max_order": 4, "forgetting_factor": 0.99,
                      "realization_interval": 10, "band": (0.0, 10.0)}


@pytest.mark.parametrize("blocking", ["single", "irregular"])
def test_on_demand_band_split_equals_the_split_of_every_block(blocking):
    """The band split of the change detection is computed when the unsplit statistic rises
    (or 256 errors are queued): the same decisions as splitting every block (ReferenceDSRA),
    on a record whose unsplit statistic rises for a change above the band (vetoed: the same
    estimator with a 45 Hz band, no split, counts it) and for one inside it."""
    rec = _above_band_record()
    n = rec[1].shape[0]
    blocks = [1] * n if blocking == "single" else list(np.diff(np.r_[0:n:37, n]))
    fast, cuts_f, models_f, _ = _trace(RecursiveDSRA, rec, blocks)
    ref, cuts_r, models_r, _ = _trace(ReferenceDSRA, rec, blocks)
    u, y, fs, cfg = rec
    unsplit, _, _, _ = _trace(RecursiveDSRA, (u, y, fs, {**cfg, "band": (0.0, 45.0)}), blocks)
    assert ref._change_count >= 1 and unsplit._change_count > ref._change_count
    assert cuts_f == cuts_r
    assert fast._change_count == ref._change_count
    if fast._split_queued:  # the errors not yet split
        fast._split_paths()
    np.testing.assert_allclose(fast._split_long, ref._ref_split[2], rtol=1e-9)
    assert [mf.time_s for mf in models_f] == [mr.time_s for mr in models_r]
