"""Automatic LTI model fitting to ETFE curves (thesis section 3.4.4, automated as asked in 6.3).

A stable rational model with a pure delay is fitted to magnitude *and* phase
over a band by relaxed vector fitting (:mod:`devices.identify.vfit`): the
delay is estimated by a coarse grid then a bounded scalar search on the fit
error, the order is chosen from an error-versus-order table, the weights are
coherence / |H| (relative error, trusting consistent bins). Several curves
(conditions) are combined first: ``high`` = upper magnitude envelope (for
HFAM, so the inverted model never over-drives a resonance), ``low`` = lower
envelope (for cancellation, never over-cancel), ``mean`` = average in dB and
phase.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np
from scipy.optimize import minimize_scalar

from ..model import ZpkModel
from . import vfit

if TYPE_CHECKING:  # annotations only: at run time they load on first use (see load_solvers)
    from ..model import ZpkModel
    from .etfe import Etfe
    from .vfit import PoleResidue

WEIGHTS = ("high", "low", "mean")
ORDER_COST_TOL = 0.005


def load_solvers():
    """The fitting machinery: ``(scipy.optimize.minimize_scalar, devices.model.ZpkModel, devices.identify.vfit)``.

    Loaded on first use rather than with this module: scipy and :mod:`devices.model` take about a second
    to import, and :class:`FitOptions` is read by every ``identify`` command before it starts recording
    (the recording process that :func:`devices.identify.pipeline.identify_device` forks must not spend
    that second). Call it to load them ahead, e.g. before forking processes that fit.
    """

    return minimize_scalar, ZpkModel, vfit


class FitError(ValueError):
    """The fit could not reach the requested error (nothing should be written)."""


@dataclass(frozen=True)
class FitOptions:
    """Options of :func:`fit_frequency_response`.

    Attributes
    ----------
    band_hz : (lo, hi) or None
        Fit band in Hz (default: the data's band).
    order : int or "auto"
        Number of poles, or chosen from the error-versus-order table.
    min_order, max_order : int
        Range of the table.
    delay_s : float or "auto"
        Pure delay; "auto" searches [0, max_delay_s].
    max_delay_s : float
    weight : {"high", "low", "mean"}
        How several curves are combined (section 3.4.4).
    use_coherence : bool
        Weight bins by coherence.
    max_rms_db, max_rms_phase_deg : float
        Requested accuracy; a worse fit raises :class:`FitError`.
    max_points : int
        Fit on at most this many bins (half uniform, half log-spaced in
        frequency); the reported errors use all bins.
    minimum_phase : bool
        Mirror right-half-plane zeros into the left half plane (same
        magnitude) and re-fit the delay, so the model inverts to a stable
        filter (section 4.2.2); the reported errors include the change.
    """

    band_hz: tuple[float, float] | None = None
    order: int | str = "auto"
    min_order: int = 1
    max_order: int = 14
    delay_s: float | str = "auto"
    max_delay_s: float = 2e-3
    weight: str = "mean"
    use_coherence: bool = True
    max_rms_db: float = 3.0
    max_rms_phase_deg: float = 20.0
    max_points: int = 400
    minimum_phase: bool = False

    def __post_init__(self) -> None:
        if self.weight not in WEIGHTS:
            raise ValueError(f"weight must be one of {WEIGHTS}, got {self.weight!r}")
        if self.order != "auto" and not (isinstance(self.order, int) and 1 <= self.order <= 60):
            raise ValueError(f"order must be 'auto' or an integer 1..60, got {self.order!r}")
        if not (1 <= self.min_order <= self.max_order <= 60):
            raise ValueError(f"need 1 <= min_order <= max_order <= 60, got {self.min_order}, {self.max_order}")
        if self.delay_s != "auto" and not (isinstance(self.delay_s, (int, float)) and 0 <= self.delay_s < 1):
            raise ValueError(f"delay_s must be 'auto' or a number in [0, 1) s, got {self.delay_s!r}")
        if self.band_hz is not None and not (len(self.band_hz) == 2 and 0 < self.band_hz[0] < self.band_hz[1]):
            raise ValueError(f"band_hz must be (lo, hi) with 0 < lo < hi, got {self.band_hz!r}")


@dataclass(frozen=True, eq=False)
class FitResult:
    """Outcome of a fit.

    Attributes
    ----------
    model : ZpkModel
    metrics : dict
        ``rms_db``, ``rms_phase_deg``, ``worst_band_db`` (max over third-octave
        bands of the band's RMS dB error), ``max_abs_db``, ``order``, ``delay_s``.
    table : list of dict
        The error-versus-order table (order, cost, rms_db, rms_phase_deg).
    f_hz, H_target, coherence : ndarray
        The (combined) curve that was fitted, over the fit band.
    """

    model: ZpkModel
    metrics: dict
    table: list = field(default_factory=list)
    f_hz: np.ndarray | None = None
    H_target: np.ndarray | None = None
    coherence: np.ndarray | None = None


# -- combining curves -----------------------------------------------------------
def _on_grid(curve: Etfe, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    if curve.f_hz.shape == f.shape and np.allclose(curve.f_hz, f):
        return curve.H, curve.coherence
    mag = np.interp(f, curve.f_hz, np.abs(curve.H))
    ph = np.interp(f, curve.f_hz, np.unwrap(np.angle(curve.H)))
    return mag * np.exp(1j * ph), np.interp(f, curve.f_hz, curve.coherence)


def combine_curves(curves: list[Etfe], weight: str = "mean") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One target curve from several ETFE curves (section 3.4.4).

    Parameters
    ----------
    curves : list of Etfe
        Same output; evaluated on the first curve's bins inside the common band.
    weight : {"high", "low", "mean"}
        Magnitude = upper envelope / lower envelope / mean in dB; phase =
        mean of the unwrapped phases (each curve shifted by whole turns to
        the first one).

    Returns
    -------
    f_hz, H, coherence : ndarray
        Coherence is the per-bin minimum over curves.
    """
    if weight not in WEIGHTS:
        raise ValueError(f"weight must be one of {WEIGHTS}, got {weight!r}")
    if not curves:
        raise ValueError("no ETFE curves to fit")
    outputs = {c.output for c in curves}
    if len(outputs) > 1:
        raise ValueError(f"cannot combine curves of different outputs {sorted(outputs)}")
    lo = max(c.f_hz[0] for c in curves)
    hi = min(c.f_hz[-1] for c in curves)
    f = curves[0].f_hz[(curves[0].f_hz >= lo) & (curves[0].f_hz <= hi)]
    if f.size < 10:
        raise ValueError(f"the curves' bands overlap in only {f.size} bins")
    Hs, cohs = zip(*(_on_grid(c, f) for c in curves))
    mags = np.abs(np.vstack(Hs))
    for c, m in zip(curves, mags):
        if not np.all(np.isfinite(m)) or np.any(m == 0):
            raise ValueError(f"ETFE curve {c.label or c.output!r} has zero or non-finite values at "
                             f"{int(np.sum(~(np.isfinite(m) & (m > 0))))} bins (did the output ever change?)")
    phases = np.unwrap(np.angle(np.vstack(Hs)), axis=1)
    phases -= 2 * np.pi * np.round((phases[:, :1] - phases[0, 0]) / (2 * np.pi))
    if weight == "high":
        mag = mags.max(axis=0)
    elif weight == "low":
        mag = mags.min(axis=0)
    else:
        mag = np.exp(np.log(mags).mean(axis=0))
    return f, mag * np.exp(1j * phases.mean(axis=0)), np.vstack(cohs).min(axis=0)


# -- error figures ----------------------------------------------------------------
def fit_errors(f_hz: np.ndarray, H_data: np.ndarray, H_fit: np.ndarray) -> dict:
    """Error figures of a fit over the given bins.

    Returns
    -------
    dict
        ``rms_db``: RMS of 20 log10 |H_fit/H_data|; ``rms_phase_deg``: RMS of
        the wrapped phase difference; ``max_abs_db``; ``worst_band_db``: the
        largest RMS dB error among third-octave bands holding >= 3 bins.
    """
    ratio = H_fit / H_data
    err_db = 20 * np.log10(np.abs(ratio))
    err_deg = np.degrees(np.angle(ratio))
    worst = 0.0
    edges = f_hz[0] * 2.0 ** (np.arange(0, np.log2(f_hz[-1] / f_hz[0]) * 3 + 1) / 3)
    for a, b in zip(edges[:-1], np.append(edges[1:-1], f_hz[-1] * 1.0001)):
        sel = (f_hz >= a) & (f_hz < b)
        if np.count_nonzero(sel) >= 3:
            worst = max(worst, float(np.sqrt(np.mean(err_db[sel] ** 2))))
    if edges.size < 2:
        worst = float(np.sqrt(np.mean(err_db**2)))
    return {"rms_db": float(np.sqrt(np.mean(err_db**2))), "rms_phase_deg": float(np.sqrt(np.mean(err_deg**2))),
            "max_abs_db": float(np.max(np.abs(err_db))), "worst_band_db": worst}


def _cost(H_fit, H, w_c) -> float:
    """Coherence-weighted RMS of |ln(H_fit/H)| (nepers and radians)."""
    e = np.log(H_fit / H)
    return float(np.sqrt(np.sum(w_c * np.abs(e) ** 2) / np.sum(w_c)))


# -- fitting ------------------------------------------------------------------------
class _Problem:
    """Fit data on a (subsampled) grid and the cost of a (order, delay) fit."""

    def __init__(self, f_hz, H, coh, max_points):
        # half the points uniform in frequency (resolves high resonances), half log-spaced (the low decade,
        # which a Bode plot shows as much of, would otherwise get only a few per cent of the bins)
        half = max(min(max_points, f_hz.size) // 2, 1)
        idx = np.unique(np.concatenate([np.linspace(0, f_hz.size - 1, half).round(),
                                        np.geomspace(1, f_hz.size, half).round() - 1]).astype(int))
        self.f = f_hz[idx]
        self.s = 2j * np.pi * self.f
        self.H = H[idx]
        self.w_c = coh[idx]
        self.w = self.w_c / np.abs(self.H)
        self._warm: dict[int, np.ndarray] = {}
        self._minimize_scalar, _, vfit = load_solvers()
        self._vector_fit_both = vfit.vector_fit_both

    def fit(self, order: int, delay_s: float, n_iter: int = 15, warm: bool = False) -> tuple[PoleResidue, float]:
        """VF at ``order`` on the data with ``delay_s`` removed; returns (model, cost).

        ``warm``: start from the poles of the last fit at this order (delay searches move smoothly).
        """
        Hd = self.H * np.exp(self.s * delay_s)  # remove the delay, fit the rational part
        poles0 = self._warm.get(order) if warm else None
        # strictly proper fit, and the residues with a direct term on its poles
        pr, prd = self._vector_fit_both(self.s, Hd, self.w, order, n_iter=n_iter, poles0=poles0, tol=1e-7)
        best = (pr, _cost(pr(self.s), Hd, self.w_c))
        cost_d = _cost(prd(self.s), Hd, self.w_c)
        if cost_d < 0.98 * best[1]:  # prefer the strictly proper model unless the direct term clearly helps
            best = (prd, cost_d)
        self._warm[order] = pr.poles
        return best

    def best_delay(self, order: int, d_lo: float, d_hi: float, n_grid: int = 9, xatol: float = 2e-7) -> float:
        """Delay minimizing the cost at ``order``: grid over [d_lo, d_hi], then bounded Brent."""
        grid = np.linspace(d_lo, d_hi, n_grid)
        costs = [self.fit(order, d, n_iter=8, warm=j > 0)[1] for j, d in enumerate(grid)]
        i = int(np.argmin(costs))
        step = grid[1] - grid[0] if n_grid > 1 else d_hi - d_lo
        a, b = max(d_lo, grid[i] - step), min(d_hi, grid[i] + step)
        self.fit(order, grid[i], n_iter=8)
        res = self._minimize_scalar(lambda d: self.fit(order, d, n_iter=8, warm=True)[1], bounds=(a, b),
                                    method="bounded", options={"xatol": xatol})
        cands = [(costs[i], grid[i]), (float(res.fun), float(res.x))]
        return min(cands)[1]


def fit_frequency_response(f_hz, H, coherence=None, options: FitOptions | None = None, *,
                           output: str = "accel_m_s2", grip_N=None, source: str = "",
                           extra_fit: dict | None = None) -> FitResult:
    """Fit a stable zpk model with pure delay to a frequency response.

    Parameters
    ----------
    f_hz : ndarray, shape (m,)
        Frequencies in Hz (increasing).
    H : ndarray of complex, shape (m,)
        Measured response (output per A).
    coherence : ndarray, shape (m,), optional
        Bin weights in [0, 1] (default 1).
    options : FitOptions

    Returns
    -------
    FitResult

    Raises
    ------
    FitError
        If the best model misses ``options.max_rms_db`` or ``max_rms_phase_deg``.
    ValueError
        For bad data (NaN, zero, too few bins, band outside the data).
    """
    _, ZpkModel, vfit = load_solvers()
    opt = options or FitOptions()
    f_hz = np.asarray(f_hz, dtype=float)
    H = np.asarray(H, dtype=complex)
    coh = np.ones_like(f_hz) if coherence is None or not opt.use_coherence else np.asarray(coherence, float)
    if not (np.all(np.isfinite(f_hz)) and np.all(np.isfinite(H)) and np.all(np.abs(H) > 0)):
        raise ValueError("frequency response has NaN/inf or zero values")
    lo, hi = opt.band_hz or (f_hz[0], f_hz[-1])
    if lo < f_hz[0] * 0.999 or hi > f_hz[-1] * 1.001:
        raise ValueError(f"fit band {lo}-{hi} Hz lies outside the data's band {f_hz[0]:.4g}-{f_hz[-1]:.4g} Hz")
    sel = (f_hz >= lo) & (f_hz <= hi)
    f, Hb, cb = f_hz[sel], H[sel], np.clip(coh[sel], 1e-3, 1.0)
    if f.size < 10:
        raise ValueError(f"fit band {lo}-{hi} Hz holds only {f.size} frequency points")
    prob = _Problem(f, Hb, cb, opt.max_points)
    orders = [opt.order] if opt.order != "auto" else list(range(opt.min_order, opt.max_order + 1))

    def order_table(delay_s):
        fits_, table_ = {}, []
        for n in orders:
            pr_, cost_ = prob.fit(n, delay_s)
            fits_[n] = pr_
            table_.append({"order": n, "cost": cost_})
        best = min(row["cost"] for row in table_)
        # parsimony: the lowest order within 20 % (+0.005 Np, about 0.04 dB / 0.3 deg) of the best
        n_ = next(row["order"] for row in table_ if row["cost"] <= 1.2 * best + ORDER_COST_TOL)
        return fits_, table_, n_

    if opt.delay_s == "auto":
        # delay first at a middle order, then again at the order that table picks; the table is redone
        # if the delay moved (delay and high-frequency poles trade against each other)
        n0 = opt.order if opt.order != "auto" else min(max(opt.max_order // 2, opt.min_order), opt.max_order)
        delay = prob.best_delay(n0, 0.0, opt.max_delay_s)
        fits, table, chosen = order_table(delay)
        if chosen != n0:
            d1 = prob.best_delay(chosen, 0.0, opt.max_delay_s)
            if abs(d1 - delay) > 1e-6:
                fits1, table1, chosen1 = order_table(d1)
                c_old = next(r["cost"] for r in table if r["order"] == chosen)
                c_new = next(r["cost"] for r in table1 if r["order"] == chosen1)
                if c_new <= c_old * 1.2 + ORDER_COST_TOL:
                    delay, fits, table, chosen = d1, fits1, table1, chosen1
        # polish: a narrow, fine search around the delay at the chosen order (sub-microsecond)
        d2 = prob.best_delay(chosen, max(0.0, delay - 1e-6), delay + 1e-6, n_grid=3, xatol=1e-10)
        pr2, c2 = prob.fit(chosen, d2)
        if c2 < next(r["cost"] for r in table if r["order"] == chosen):
            delay, fits[chosen] = d2, pr2
            next(r for r in table if r["order"] == chosen)["cost"] = c2
    else:
        delay = float(opt.delay_s)
        fits, table, chosen = order_table(delay)
    pr = fits[chosen]
    zeros, poles, k = vfit.to_zpk(pr, prob.s)
    for row in table:  # report the table in dB/degrees on all bins
        m = _model(fits[row["order"]], prob.s, delay, output)
        row.update({k2: round(v, 4) for k2, v in fit_errors(f, Hb, m.frequency_response(f)).items()
                    if k2 in ("rms_db", "rms_phase_deg")})
        row["cost"] = round(row["cost"], 6)
    n_rhp = int(np.sum(zeros.real > 0))
    if opt.minimum_phase and n_rhp:
        zeros, delay = _reflect_zeros(zeros, poles, k, f, Hb, cb, opt.max_delay_s)
    model = ZpkModel(zeros, poles, k, delay, output=output, band_hz=(float(f[0]), float(f[-1])), grip_N=grip_N)
    metrics = fit_errors(f, Hb, model.frequency_response(f))
    metrics.update({"order": int(model.order), "n_zeros": int(model.zeros_rad_s.size), "delay_s": float(delay),
                    "weight": opt.weight, "method": "relaxed vector fitting, delay by bounded search",
                    "coherence_mean": float(np.mean(cb)),
                    "nonminimum_phase_zeros": int(np.sum(model.zeros_rad_s.real > 0)),
                    "reflected_zeros": n_rhp if opt.minimum_phase else 0})
    if extra_fit:
        metrics.update(extra_fit)
    result_fit = {**metrics, "order_table": table}
    model = ZpkModel(model.zeros_rad_s, model.poles_rad_s, model.gain, model.delay_s, output=output,
                     band_hz=model.band_hz, grip_N=grip_N, fit=result_fit, source=source)
    result = FitResult(model, metrics, table, f, Hb, cb)
    if metrics["rms_db"] > opt.max_rms_db or metrics["rms_phase_deg"] > opt.max_rms_phase_deg:
        raise FitError(
            f"fit did not reach the requested error over {f[0]:.4g}-{f[-1]:.4g} Hz: best order {chosen} gives "
            f"RMS {metrics['rms_db']:.2f} dB (max {opt.max_rms_db}) and {metrics['rms_phase_deg']:.1f} deg "
            f"(max {opt.max_rms_phase_deg}); error-vs-order table: "
            + ", ".join(f"{r['order']}: {r['rms_db']:.2f} dB/{r['rms_phase_deg']:.1f} deg" for r in table)
            + "; no model written")
    return result


def _reflect_zeros(zeros, poles, k, f, H, coh, max_delay_s):
    """Mirror right-half-plane zeros into the left half plane and re-fit the delay.

    |j w - z| = |j w + conj(z)|, so the magnitude is unchanged; the phase the
    reflection adds is partly a delay, which is re-estimated on the band.
    Returns (zeros, delay_s).
    """
    minimize_scalar = load_solvers()[0]
    z = np.where(zeros.real > 0, -zeros.real + 1j * zeros.imag, zeros)
    s_ = 2j * np.pi * f
    base = k * np.prod(s_[:, None] - z, axis=1) / np.prod(s_[:, None] - poles, axis=1)
    res = minimize_scalar(lambda d: _cost(base * np.exp(-s_ * d), H, coh), bounds=(0.0, 2 * max_delay_s),
                          method="bounded", options={"xatol": 1e-9})
    return z, float(res.x)


def _model(pr: PoleResidue, s_ref, delay, output) -> ZpkModel:
    _, ZpkModel, vfit = load_solvers()
    z, p, k = vfit.to_zpk(pr, s_ref)
    return ZpkModel(z, p, k, delay, output=output)


DEFAULT_LOW_HZ = 10.0  # below about 10 Hz the user's own motion dominates (sec. 3.4, 3.4.3)


def default_band(curves: list[Etfe]) -> tuple[float, float]:
    """Fit band when none is given: the common swept band from 10 Hz up, cut where any curve's output
    falls below its quantization (``Etfe.resolvable_hi_hz``)."""
    lo = max(max(c.f_hz[0] for c in curves), DEFAULT_LOW_HZ)
    hi = min(min(c.f_hz[-1] for c in curves), min(c.resolvable_hi_hz for c in curves))
    if not hi > 2 * lo:
        raise ValueError(f"no usable fit band: {lo:.4g}-{hi:.4g} Hz (swept band and quantization-resolvable "
                         "output); use a larger sweep amplitude or give --band")
    return float(lo), float(hi)


def fit_etfes(curves: list[Etfe], options: FitOptions | None = None, *, source: str = "",
              grip_N=None) -> FitResult:
    """Combine ETFE curves (``options.weight``) and fit one model to them.

    Without ``options.band_hz`` the band is :func:`default_band`.
    """
    opt = options or FitOptions()
    if opt.band_hz is None:
        opt = replace(opt, band_hz=default_band(curves))
    f, H, coh = combine_curves(curves, opt.weight)
    if grip_N is None and len(curves) == 1:
        grip_N = curves[0].grip_N
    extra = {"n_curves": len(curves), "n_trials": int(sum(c.n_trials for c in curves))}
    return fit_frequency_response(f, H, coh, opt, output=curves[0].output, grip_N=grip_N, source=source,
                                  extra_fit=extra)
