"""Spurious-mode rejection for one realization: is a pole pair a physical mode or noise?

An over-sized subspace model (order above twice the number of modes, as the DSRA needs when the
noise is coloured or the mode count unknown) always returns extra pole pairs that fit the noise.
A pole pair is kept as a *stable* (physical) mode when all of these hold:

1. **Stable across model orders** (the stabilization diagram): realizations of the check orders
   from the same projection (cheap: :func:`~sysid_node.core.realization.shift_poles`) have a
   pole within ``STABLE_FREQUENCY_TOL`` (1 %, the classical stabilization criterion) of its
   frequency, in every check order but at most ``STABLE_MISSES`` (one) of them. Noise poles
   move when the order changes; physical ones do not. One miss is allowed because the lowest
   check order (n - 4) has two pole pairs fewer than the model: a mode that has just appeared
   (little of the memory holds it yet) or the weakest one is legitimately missing there.
2. **Above the noise floor**: the mode's spectral peak over the innovation's spectral level
   (``ModalParameters.snr``) exceeds what the noise alone produces somewhere in the band: the
   periodogram of white noise has M = (band width) x (effective data length) independent
   cells, each exponentially distributed about the floor, so its largest one exceeds
   ln(M / alpha) only with probability alpha (``NOISE_PEAK_ALPHA`` = 1 %). A model fitted to
   noise places poles on such fluctuations; a physical mode stands above all of them.
3. **Above the overfit level**: a least-squares fit with r regressors to N_eff samples of pure
   noise "explains" a fraction of it that exceeds chi2_r(1 - alpha) / N_eff only with
   probability alpha (its R^2 is Beta(r/2, (N_eff - r)/2) distributed). The (A2) regression has
   r = i (m + l) + i m regressors per output, so a pole pair whose variance over the innovation
   variance (``ModalParameters.contribution``, summed over the l outputs) is below
   l chi2_r(1 - alpha) / N_eff may be nothing but that overfit: early on (few samples, many
   regressors) noise poles carry a real-looking share of the output.
4. **Determined frequency** (batch only): the 99 % confidence interval of the frequency
   (delta-method standard deviation, ``modal.py``) is narrower than the tracking gate,
   ``z_0.995 sigma_f / f <= frequency_gate``. A batch model is one realization of the whole
   record, and this is its only consistency check. The recursive estimator does not apply it
   (``frequency_gate=None``): over a memory of a few periods a lightly damped low mode's single
   realization has a wide interval (sd 2-7 % for the paper example's 2 Hz mode with 16 block
   rows, a 2.2 %-damped drifting 2.5 Hz mode at 200 Hz, and any mode in the seconds after a
   gap restarts the window) although the median over successive realizations, which the
   tracker gates (``tracking.py``), follows it within 2 %; the test rejected such true modes for
   seconds while the noise modes it was meant for are caught by tests 1-3 (the paper example
   had no false tracked mode without it).

5. **Not the input's own** (recursive, with a measured input): where the recent input is
   narrow-band (a sweep's current stretch, a sine dwell), the future inputs are predicted by
   the past ones, the input is not persistently exciting of order 2i there, and the oblique
   projection (A2) splits the output between the past data and the future inputs
   arbitrarily: the state then carries the input's own oscillation (random suite: tracked
   "modes" that follow a swept input through the band). The recent input's spectrum is the
   Hann-tapered Bartlett spectrum of its 2i window samples (the realization's resolution)
   over an exponential memory of ``INPUT_RECENT_WINDOWS`` windows, over its mean
   (:func:`input_concentration`: 1 for white noise); a pole pair where it stands at least
   ``INPUT_OWN_LEVEL`` and ``INPUT_OWN_PROMINENCE`` times above its lowest value within
   ``INPUT_PEAK_SPAN`` (two bins at least) on both sides is not a mode *of this realization*
   (:func:`input_own`). A red or band-pass input has no such peak (its low end falls from DC,
   its pass band is flat). A structural mode the sweep is passing through is rejected for that
   passage only: it is identified again once the sweep has moved on.

Test 3 bounds a single realization's overfit, and a lightly damped mode's young share can sit
below it for seconds (random suite: a 0.2 %-damped 43.8 Hz mode at 145 Hz, one output, within
0.5 % in 69 of 83 realizations and below the level in 55). Noise poles move from one
realization to the next as the data in memory change; a physical mode stays. :class:`Persistence`
lifts test 3 for a pole pair that passed the other tests in ``PERSIST_REALIZATIONS`` successive
realizations within ``PERSIST_FREQUENCY_TOL`` of the median of those (and within the MAC gate).
On pure noise through the pipeline (10 s records, 4 each, white noise plus three 20-50 %-damped
resonances: 145 Hz one output, 231 Hz two outputs) the longest such run of a pole pair below the
overfit level was 5 and 4 realizations (178 and 308 of them); on white noise (8 records of 10 s
each at 200, 500 and 876 Hz, one and two outputs: 218-375 such pole pairs per set) it was 6, 6,
6, 6, 5 and 5 over the whole record and at most 3 while the memory fills (where the pipeline
lifts). A lifted pole pair must then stay put for the tracker's confirmation
(``tracking_confirm_count`` more in a row) as well: a noise pole pair would need about twice
the longest run seen.
The pipeline lifts test 3 only while the estimator's memory fills (start-up, where a young
mode's share is smallest against the level): later, pole pairs that are not modes persist too
(random suite: a jumped mode's old frequency while its data leave the memory, draw 12; weak
lightly damped poles beside a strong mode, draw 6), and the full memory passes the weak modes.
A pole pair within ``SIDEBAND_BINS`` bins of the realization's resolution fs/(2i) of a stronger
stable mode is not resolved from it (two bins: the main-lobe half-width of the Hann taper test
5 uses at that resolution) and persists as the strong mode does, so it is not a candidate
(``flag_spurious`` ``resolution_hz``; random suite draw 6: 77.6 Hz, 1.8 bins of 2.46 Hz above
a strong 73.2 Hz mode, lifted and tracked false at 4.3 and 7.0-7.4 s). With a measured input,
neither is a pole pair in a band the input has not excited over the estimator's memory (its
Bartlett spectrum over its mean, :func:`input_concentration` of the memory's input windows,
below ``INPUT_EXCITED_LEVEL``):
the input is not persistently exciting there, the projection is undetermined in that band and
its pole pair stays put because the input's deficiency does (drawn swept-input record 705: a
0.02 %-damped 104.2 Hz pole pair, lifted in 13 realizations, a false track for 0.8 s, while the
sweep was at 60-70 Hz: concentration there 6e-4; a white input's lowest 0.049 over 33 068
pole pairs: 200, 500 and 876 Hz, one and two inputs, 4 records of 10 s each, 1 % quantiles
0.35-0.78).

Consistency over successive realizations, shape consistency (MAC) and the ranking by
contribution are the tracker's part (``tracking.py``).
"""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy import optimize, stats

from .modal import ModalParameters, mac_matrix

#: Relative frequency change allowed between model orders (Peeters & De Roeck 1999).
STABLE_FREQUENCY_TOL = 0.01
#: Two-sided 99 % quantile of the normal distribution (confidence interval of the frequency).
Z_99 = 2.5758293035489004
#: False-alarm probability of the noise-peak test (over the whole band).
NOISE_PEAK_ALPHA = 0.01
#: Check orders relative to the realized order n: the same modes must appear with two pole
#: pairs less and two and four more (n - 4, n + 4, n + 8).
CHECK_ORDER_STEPS = (-4, 4, 8)
#: Check orders in which a stable mode may be missing.
STABLE_MISSES = 1
#: Test 5: input concentration (Bartlett spectrum over its mean: 1 for white noise, about 2i/3
#: for a sinusoid over 2i samples) from which a pole pair may be the input's own ...
INPUT_OWN_LEVEL = 3.0
#: ... over the recent windows: an exponential memory of this many window lengths 2i ...
INPUT_RECENT_WINDOWS = 2
#: ... when it stands this factor above its lowest value within INPUT_PEAK_SPAN (relative
#: frequency, two Bartlett bins at least) on both sides.
INPUT_OWN_PROMINENCE = 2.0
INPUT_PEAK_SPAN = 0.1
#: Persistence: successive realizations in which a pole pair that failed test 3 alone (or passed
#: all tests) stayed within PERSIST_FREQUENCY_TOL of the run's median frequency ...
PERSIST_REALIZATIONS = 6
PERSIST_FREQUENCY_TOL = 0.005
#: ... and within this MAC of the run's latest shape (more than one output).
PERSIST_MAC = 0.9
#: A candidate is not within this many bins fs/(2i) of a stronger stable mode (not resolved
#: from it: the Hann main lobe's half-width, as test 5's two bins).
SIDEBAND_BINS = 2.0
#: ... nor where the input over the estimator's memory (its Bartlett spectrum over its mean,
#: :func:`input_concentration`) is below this level: a band the input has not excited yet.
INPUT_EXCITED_LEVEL = 0.01


def check_orders(order: int, top: int) -> list[int]:
    """The check orders for a realization of ``order``, within [2, ``top``] (``top``: the
    largest order the block rows allow); steps that do not fit are replaced by the nearest
    free orders below."""
    want = len(CHECK_ORDER_STEPS)
    out = [order + d for d in CHECK_ORDER_STEPS if 2 <= order + d <= top and d]
    k = 2
    while len(out) < want and order - k >= 2:
        if order - k not in out:
            out.append(order - k)
        k += 2
    return sorted(out)


def pole_frequencies(poles: np.ndarray, fs: float) -> np.ndarray:
    """Natural frequencies [Hz] of the complex discrete poles with positive imaginary part."""
    mu = poles[poles.imag > 1e-7 * np.maximum(1.0, np.abs(poles))]
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.abs(np.log(mu.astype(complex))) * fs / (2 * np.pi)
    return f[np.isfinite(f)]


def input_concentration(cov: np.ndarray, n_inputs: int, freqs_hz: np.ndarray,
                        fs: float) -> np.ndarray:
    """Per frequency [Hz]: the largest over the inputs of e' M e / tr M, M the covariance of an
    input's 2i successive samples (``cov``: the (2 i m, 2 i m) covariance of the recent
    windows' inputs [u_p; u_f], sample-major, input c at rows c, c + m, ...) and e the
    Hann-tapered phasor at that frequency over them (taper of unit mean square): the Bartlett
    spectrum over its mean, about 1 for a white or flat multisine input, up to about 2i/3 for a
    sinusoid. Zeros without inputs."""
    f = np.atleast_1d(np.asarray(freqs_hz, dtype=float))
    m = int(n_inputs)
    if m == 0 or f.size == 0 or cov is None or cov.size == 0:
        return np.zeros(f.size)
    n = cov.shape[0] // m
    taper = np.hanning(n + 2)[1:-1]  # leakage of a strong low-frequency input stays local
    taper /= np.sqrt(np.mean(taper**2))
    e = taper * np.exp(-2j * np.pi * np.outer(f, np.arange(n)) / fs)  # (k, 2 i)
    q = np.zeros(f.size)
    for c in range(m):
        mc = cov[c::m, c::m]
        tr = float(np.trace(mc))
        if tr > 0:
            q = np.maximum(q, np.sum((e.conj() @ mc) * e, axis=1).real / tr)
    return q


def input_own(cov: np.ndarray, n_inputs: int, freqs_hz: np.ndarray, fs: float) -> np.ndarray:
    """Per frequency [Hz]: is it in a *peak* of the recent input's spectrum (test 5)? The
    concentration there (:func:`input_concentration`) is at least ``INPUT_OWN_LEVEL`` and at
    least ``INPUT_OWN_PROMINENCE`` times its lowest value within ``INPUT_PEAK_SPAN`` (at least two
    Bartlett bins fs / 2i) below and above: a sweep's current stretch or a sine dwell, not the
    low end of a red (falling) input spectrum nor a flat band-pass one."""
    f = np.atleast_1d(np.asarray(freqs_hz, dtype=float))
    if f.size == 0 or int(n_inputs) == 0 or cov is None or cov.size == 0:
        return np.zeros(f.size, bool)
    half = max(cov.shape[0] // int(n_inputs), 1)  # 2 i
    span = np.maximum(INPUT_PEAK_SPAN * f, 2.0 * fs / half)
    steps = np.arange(1, 5) / 4.0
    grid = np.concatenate([np.maximum(f[:, None] - span[:, None] * steps, 0.0), f[:, None],
                           f[:, None] + span[:, None] * steps], axis=1)  # (k, 9), DC at most
    q = input_concentration(cov, n_inputs, grid.ravel(), fs).reshape(grid.shape)
    at, below, above = q[:, 4], q[:, :4].min(axis=1), q[:, 5:].min(axis=1)
    return (at >= INPUT_OWN_LEVEL) & (at >= INPUT_OWN_PROMINENCE * np.maximum(below, above))


def overfit_threshold(regressors: int, n_outputs: int, n_eff: float) -> float:
    """Contribution (variance over innovation variance, summed over the outputs) that noise
    fitted by ``regressors`` least-squares regressors per output reaches with probability
    NOISE_PEAK_ALPHA from ``n_eff`` effective samples: l chi2_r(1 - alpha) / N_eff."""
    return n_outputs * _chi2_quantile(max(int(regressors), 1)) / max(float(n_eff), 1.0)


@functools.lru_cache(maxsize=64)
def _chi2_quantile(dof: int) -> float:
    """chi2_dof(1 - NOISE_PEAK_ALPHA), once per window layout (scipy's ppf costs as much as
    a small eigendecomposition, and every realization asks for it)."""
    return float(stats.chi2.ppf(1.0 - NOISE_PEAK_ALPHA, dof))


def noise_peak_threshold(band_width_hz: float, duration_s: float) -> float:
    """Largest peak-to-floor ratio that white noise reaches with probability NOISE_PEAK_ALPHA
    over ``band_width_hz`` observed for ``duration_s`` (effective) seconds: ln(M / alpha),
    M = band width x duration independent periodogram cells (at least 1)."""
    cells = max(float(band_width_hz) * float(duration_s), 1.0)
    return math.log(cells / NOISE_PEAK_ALPHA)


def flag_spurious(
    modes: list[ModalParameters],
    check_frequencies: list[np.ndarray],
    frequency_gate: float | None = 0.05,
    snr_threshold: float = 1.0,
    contribution_threshold: float = 0.0,
    in_input_peak: np.ndarray | None = None,
    resolution_hz: float = 0.0,
    input_excited: np.ndarray | None = None,
) -> None:
    """Set ``stable`` and ``stable_orders`` of each mode (in place) from the tests above;
    ``check_frequencies`` holds the pole frequencies [Hz] of each check order,
    ``snr_threshold`` the noise-peak level (:func:`noise_peak_threshold`),
    ``contribution_threshold`` the overfit level (:func:`overfit_threshold`);
    ``frequency_gate`` None skips test 4; ``in_input_peak`` per mode: in a peak of the recent
    input's spectrum (:func:`input_own`; None skips test 5); ``resolution_hz`` fs/(2i): a mode
    within ``SIDEBAND_BINS`` of it from a stronger stable mode is not ``overfit_only`` (0: no
    such check), nor one where ``input_excited`` (per mode, None: not checked) is False."""
    for k, md in enumerate(modes):
        f = md.frequency_hz
        hits = sum(
            bool(fc.size and np.min(np.abs(fc - f)) <= STABLE_FREQUENCY_TOL * f)
            for fc in check_frequencies
        )
        md.stable_orders = int(hits)
        above_floor = not math.isfinite(md.snr) or md.snr >= snr_threshold
        above_overfit = not math.isfinite(md.contribution) or (
            md.contribution >= contribution_threshold
        )
        rel_std = md.frequency_std_hz / max(f, 1e-300)
        determined = (frequency_gate is None or not math.isfinite(rel_std)
                      or Z_99 * rel_std <= frequency_gate)
        need = max(len(check_frequencies) - STABLE_MISSES, min(len(check_frequencies), 1))
        own = in_input_peak is not None and bool(in_input_peak[k])
        others = hits >= need and above_floor and determined and not own
        md.stable = others and above_overfit
        excited = input_excited is None or bool(input_excited[k])
        md.overfit_only = others and not above_overfit and excited
    # within SIDEBAND_BINS bins of a stronger stable mode: maybe its window sideband
    strong = np.array([(md.frequency_hz, md.contribution) for md in modes if md.stable])
    if resolution_hz > 0 and strong.size:
        for md in modes:
            near = np.abs(strong[:, 0] - md.frequency_hz) <= SIDEBAND_BINS * resolution_hz
            md.overfit_only &= not np.any(near & (strong[:, 1] > md.contribution))


class Persistence:
    """Lift test 3 for pole pairs that persist over successive realizations (module docstring).

    A *run* follows one pole pair through successive realizations: each realization's
    candidates (modes that passed every test, or all but test 3: ``overfit_only``) extend the
    runs of the previous one by an assignment on the relative frequency distance to the run's
    median (within ``frequency_tol``) and the MAC to its latest shape (at least ``mac_gate``);
    a run not extended ends. An ``overfit_only`` mode on a run of ``realizations`` or more
    (itself included) is marked ``stable``.
    """

    def __init__(self, realizations: int = PERSIST_REALIZATIONS,
                 frequency_tol: float = PERSIST_FREQUENCY_TOL,
                 mac_gate: float = PERSIST_MAC) -> None:
        self.realizations = int(realizations)
        self.frequency_tol = float(frequency_tol)
        self.mac_gate = float(mac_gate)
        #: per run: (frequencies [Hz] of its realizations, latest shape)
        self._runs: list[tuple[list[float], np.ndarray]] = []

    def reset(self) -> None:
        self._runs = []

    def apply(self, modes: list[ModalParameters], lift: bool = True) -> None:
        """Extend the runs with one realization's ``modes`` and mark the persistent ones
        (``lift`` False: extend the runs only)."""
        cand = [md for md in modes if md.stable or md.overfit_only]
        pairs = self._assign(cand)
        runs = []
        for k, md in enumerate(cand):
            past = self._runs[pairs[k]][0][-(4 * self.realizations):] if k in pairs else []
            freqs = [*past, md.frequency_hz]
            runs.append((freqs, np.asarray(md.shape)))
            if lift and md.overfit_only and len(freqs) >= self.realizations:
                md.stable = True
        self._runs = runs

    def _assign(self, cand: list[ModalParameters]) -> dict[int, int]:
        """Candidate index -> run index, within the gates (minimal summed frequency distance)."""
        if not cand or not self._runs:
            return {}
        ref = np.array([np.median(fr) for fr, _ in self._runs])
        f = np.array([md.frequency_hz for md in cand])
        cost = np.abs(f[:, None] / ref[None, :] - 1.0) / self.frequency_tol
        size_c = np.array([np.size(md.shape) for md in cand])
        size_r = np.array([np.size(shape) for _, shape in self._runs])
        for n in set(size_c[size_c > 1].tolist()) & set(size_r.tolist()):
            ic, ir = np.flatnonzero(size_c == n), np.flatnonzero(size_r == n)
            a = np.array([np.ravel(cand[k].shape).astype(complex) for k in ic])
            b = np.array([np.ravel(self._runs[j][1]).astype(complex) for j in ir])
            block = cost[np.ix_(ic, ir)]
            block[mac_matrix(a, b) < self.mac_gate] = np.inf
            cost[np.ix_(ic, ir)] = block
        ok = np.isfinite(cost) & (cost <= 1.0)
        rows, cols = optimize.linear_sum_assignment(np.where(ok, cost, 1e6))
        return {int(r): int(c) for r, c in zip(rows, cols, strict=True) if ok[r, c]}
