"""The DDPC layer's optimal control problem, the paper's Eq. (10).

Decision variables u(0|t) … u(T|t), the predicted outputs y(1|t) … y(T|t) and one slack ε(k|t) per
deck and step. With the multistep model (3), z_p holding the measured past and u(0|t):

    min  J = J_y + σ J_u + τ J_ε + γ J_Δu                                              (9)
    J_y  = Σ_{k=0..T} ‖y(k|t) − T_opt(k|t) 1₃‖²       (y(0|t) = the measured y(t))
    J_u  = Σ_{k=0..T} (u(k|t) − T_opt(k|t))²
    J_ε  = Σ_{k=1..T} ‖ε(k|t)‖²
    J_Δu = (u(0|t) − u(t−1))² + Σ_{k=1..T} (u(k|t) − u(k−1|t))²
    s.t. y_f = Ĥ [z_p; u_f; d_f]                                                       (3)
         |y(k|t) − T_rule(k|t)| ≤ T_max + ε(k|t),  ε(k|t) ≥ 0,   k = 1 … T            (4), (5)
         |u(k|t) − T_rule(k|t)| ≤ u_band,                       k = 0 … T            (6)
         |u(0|t) − u(t−1)| ≤ ΔT_max,  |u(k|t) − u(k−1|t)| ≤ ΔT_max,  k = 1 … T       (7)

The ``margin`` objective (:data:`OBJECTIVES`) adds what a setpoint costs under the HVAC's own
rules (Section II.B): between its ambient thresholds the unit leaves cooling (heating) for the
mixed state, which heats (cools) a deck, once the coach's mean room temperature lies
``climate_room_band_k`` (0.5 K) below (above) T_ref. A T_ref the room does not follow is not
free. So T_ref stays within ``margin_k`` (half that band) of the mean predicted room
temperature, softly, with one slack ξ per row:

    |u(k|t) − ȳ(k|t)| ≤ m + ξ,  k = 0 … T;   |u(k|t) − ȳ(k+1|t)| ≤ m + ξ,  k = 0 … T−1
    ξ ≥ 0,  J += τ_m Σ ξ²

with ȳ the mean over the decks (ȳ(0|t) measured) and m = ``margin_k``; ``paper`` is Eq. (10)
alone.

The ``states`` objective is Eq. (10) with T_ref kept where the unit's state stays as the
rule-based coach would have it. Between its ambient thresholds (heating below T_amb = T_ref −
``heat_below_k``, cooling above T_ref − ``cool_above_k``) the unit takes the state the decks ask
for, and a deck colder than T_ref asks for heat: a T_ref raised above the coldest deck turns a
cooling unit mixed, heating that deck while the others are cooled, and keeps it there (October's
trap). So u(k) may rise above T_rule(k) only as far as the coldest measured deck less a margin
δ, or as far as the ambient temperature keeps the unit cooling whatever the decks ask:

    u(k) ≤ max(T_rule(k), min_i y_i(t) − δ, T_amb(k) + cool_above_k),   k = 0 … T

except where T_amb(k) < T_rule(k) − heat_below_k: there the unit heats whatever the decks ask for
every T_ref ≥ T_rule, and a raise cannot change its state.

(T_amb(0) measured, T_amb(k ≥ 1) forecast; relaxed to what the rate limit (7) can reach from
u(t−1), u(t−1) − (k+1) ΔT_max, so the problem stays feasible). The bound tightens the box (6)
and adds no row: the QP is the paper's, with another bound. Lowering T_ref is left free: the
mirror rule for a heating unit (T_ref no lower than the warmest deck plus δ) was measured and
costs more in service than it saves (docs/experiments.md).

Two implementations that must agree (tested on hundreds of random instances):

- :class:`DDPCProblem` (the production path): y eliminated through the model, y_f = c + G u with
  c the known part of Ĥ's input and G Ĥ's columns of u(0|t) … u(T|t), so the QP in
  x = [u; ε] has P and A fixed by the predictor and the settings. They are built once and
  handed to OSQP once; each step updates only the vectors q, l, u and warm-starts from the last
  solution.
- :class:`ReferenceProblem`: the readable formulation in cvxpy, DPP-compliant — y kept as a
  variable, everything that changes per step a ``cp.Parameter`` — so cvxpy compiles it once;
  ``rebuild=True`` builds and compiles it anew at every solve (the naive path, for the benchmark).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from trainclimate.coach.setpoint import COMFORT_BAND_K, U_BAND_K
from trainclimate.predict.base import MultistepPredictor
from trainclimate.predict.hankel import NU, NY, NZ
from trainclimate.sim.params import CoachParams

#: The objectives: the paper's Eq. (10), Eq. (10) with T_ref kept within a margin of the
#: predicted room temperature, and Eq. (10) with T_ref raised only where the HVAC's state rules
#: keep a cooling unit cooling (the module docstring).
OBJECTIVES = ("paper", "margin", "states")
#: The objective the product's layer runs unless told otherwise — the commands, the studies and
#: the service: ``states`` does not fall into the October trap and saves as much as the paper's
#: elsewhere (docs/experiments.md). :class:`OCPSettings` on its own is the paper's problem.
DEFAULT_OBJECTIVE = "states"


#: The solver's time budget per step on a live coach (the tick's real-time bound). [s]
REAL_TIME_LIMIT_S = 0.05
#: The budget in offline simulations (experiments, studies, simulated trials): far above the
#: solve times (≈ 0.1 ms), so how loaded the machine is cannot turn a step into a
#: ``solver_timeout`` fallback, and a seed's numbers are the same on every run and machine. [s]
OFFLINE_TIME_LIMIT_S = 10.0


@dataclass(frozen=True)
class OCPSettings:
    """Weights and bounds of the problem (paper, Eq. (4)–(9)).

    The default weights come from a closed-loop sweep over the five scenarios
    (docs/controller.md).

    Attributes
    ----------
    sigma, tau, gamma : float
        Weights σ, τ, γ of J_u, J_ε and J_Δu in Eq. (9); J_y has weight 1. [–]
    t_max : float
        Comfort half-band T_max of Eq. (4). [K]
    du_max : float
        Rate limit ΔT_max of Eq. (7). [K per step]
    u_band : float
        Limit on |u − T_rule| of Eq. (6), the driver's ±2 K. [K]
    time_limit_s : float
        The solver's time budget per step. [s]
    objective : str
        ``"paper"`` (Eq. (10)), ``"margin"`` (plus T_ref within ``margin_k`` of the predicted
        mean room temperature) or ``"states"`` (plus T_ref raised only where a cooling unit
        keeps cooling; see the module docstring).
    margin_k : float
        The margin m of the ``margin`` objective. [K]
    margin_weight : float
        Its slacks' weight τ_m. [–]
    state_margin_k : float
        The margin δ of the ``states`` objective: how far below the coldest deck a raised
        T_ref stays. [K]
    cool_above_k, heat_below_k : float
        The HVAC's ambient thresholds below T_ref (Section II.B): the unit cools whatever the
        decks ask for T_amb > T_ref − ``cool_above_k`` and heats for T_amb < T_ref −
        ``heat_below_k`` (default: the coach's, :class:`~trainclimate.sim.params.CoachParams`).
        [K]

    Raises
    ------
    ValueError
        If a weight or bound is not positive and finite.

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section III.C, Eqs. (4)–(9).
    """

    sigma: float = 3.0
    tau: float = 100.0
    gamma: float = 1.0
    t_max: float = COMFORT_BAND_K
    du_max: float = 0.5
    u_band: float = U_BAND_K
    time_limit_s: float = REAL_TIME_LIMIT_S
    objective: str = "paper"
    margin_k: float = 0.25
    margin_weight: float = 100.0
    state_margin_k: float = 0.3
    cool_above_k: float = CoachParams.cool_above_k
    heat_below_k: float = CoachParams.heat_below_k

    def __post_init__(self) -> None:
        if self.objective not in OBJECTIVES:
            raise ValueError(f"unknown objective {self.objective!r}: {', '.join(OBJECTIVES)}")
        for name in ("sigma", "tau", "gamma", "margin_weight"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ValueError(f"OCP weight {name} must be positive and finite")
        for name in ("t_max", "du_max", "u_band", "time_limit_s", "margin_k", "state_margin_k"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ValueError(f"OCP bound {name} must be positive and finite")
        if not (np.isfinite(self.cool_above_k) and np.isfinite(self.heat_below_k)):
            raise ValueError("the HVAC's ambient thresholds must be finite")
        if self.heat_below_k <= self.cool_above_k:
            raise ValueError("heat_below_k must exceed cool_above_k (heating below cooling)")


@dataclass
class Solution:
    """The optimum of one step's problem.

    Attributes
    ----------
    u : numpy.ndarray of shape (T+1,)
        Setpoints u(0|t) … u(T|t). [°C]
    y : numpy.ndarray of shape (T, 3)
        Predicted room temperatures y(k|t), k = 1 … T. [°C]
    eps : numpy.ndarray of shape (T, 3)
        Slacks ε(k|t), k = 1 … T. [K]
    objective : float
        J including its constant terms. [K²]
    status : str
        ``"solved"`` when optimal, else the solver's word.
    solve_time_s : float
        The solver's own time. [s]
    iterations : int
        Solver iterations (0 where not reported).
    """

    u: np.ndarray
    y: np.ndarray
    eps: np.ndarray
    objective: float
    status: str
    solve_time_s: float = 0.0
    iterations: int = 0

    @property
    def solved(self) -> bool:
        """Whether the solver reached the optimum (``status == "solved"``)."""
        return self.status == "solved"


class _Condensed:
    """What both implementations share: the model split into its known part and its u part,
    and the per-step data of the problem."""

    def __init__(self, predictor: MultistepPredictor, settings: OCPSettings):
        H = predictor.require_fit()
        self.rho, self.T = predictor.rho, predictor.horizon
        self.settings = settings
        self.predictor = predictor
        rho, T = self.rho, self.T
        self.u0_col = NZ * (rho - 1) + NY  # u(t) inside z_p
        uf = NZ * rho + np.arange(T)
        self.G = np.column_stack([H[:, self.u0_col], H[:, uf]])  # (3T, T+1)
        self.H_known = H.copy()
        self.H_known[:, self.u0_col] = 0.0
        self.H_known[:, uf] = 0.0
        #: the margin rows R u − o (o from :meth:`margin_offset`), None for the paper's objective
        self.R = None
        if settings.objective == "margin":
            M = np.kron(np.eye(T), np.full((1, NY), 1.0 / NY))  # ȳ(1…T) = M y_f
            MG = M @ self.G
            shift = np.eye(T + 1)[:T]  # u(0) … u(T−1)
            self.R = np.vstack([np.eye(T + 1) - np.vstack([np.zeros(T + 1), MG]), shift - MG])

    def margin_offset(self, c: np.ndarray, y0: np.ndarray) -> np.ndarray:
        """The margin rows' known part o: ȳ(0|t) measured, then ȳ(1…T|t)'s known part twice."""
        mc = c.reshape(self.T, NY).mean(axis=1)
        return np.concatenate([[np.mean(y0)], mc, mc])

    def data(self, y_past, u_past, d_past, d_future, t_rule, t_opt, u_prev):
        """Checked arrays and the known part c of the predicted outputs."""
        rho, T = self.rho, self.T
        u_past = np.asarray(u_past, dtype=float).reshape(-1, NU)
        if u_past.shape != (rho - 1, NU):
            raise ValueError(f"u_past must have shape ({rho - 1}, 1), got {u_past.shape}")
        t_rule = np.asarray(t_rule, dtype=float).ravel()
        t_opt = np.asarray(t_opt, dtype=float).ravel()
        for name, arr in (("t_rule", t_rule), ("t_opt", t_opt)):
            if arr.shape != (T + 1,):
                raise ValueError(f"{name} must have length {T + 1} (k = 0 … T), got {arr.shape}")
        u_prev = float(u_prev)
        # u(t) = u(0|t) is a decision: a placeholder here, zeroed in H_known
        u_all = np.vstack([u_past, [[0.0]]])
        x = self.predictor.regressor(y_past, u_all, d_past, np.zeros((T, NU)), d_future)
        if not np.all(np.isfinite(x)) or not np.all(np.isfinite(t_rule)) or not np.isfinite(u_prev):
            raise ValueError("the problem data hold NaN or infinite values")
        if not np.all(np.isfinite(t_opt)):
            raise ValueError("t_opt holds NaN or infinite values")
        c = self.H_known @ x
        y0 = np.asarray(y_past, dtype=float)[-1]
        return c, y0, t_rule, t_opt, u_prev

    def setpoint_bounds(
        self, y0, d_past, d_future, t_rule, u_prev
    ) -> tuple[np.ndarray, np.ndarray]:
        """Bounds on u(0|t) … u(T|t): the box (6), its top lowered by the state rule for
        ``states`` (the module docstring).

        Parameters
        ----------
        y0 : numpy.ndarray of shape (3,)
            The measured decks y(t). [°C]
        d_past, d_future : array-like of shapes (ρ, 5) and (T, 5)
            Measured and forecast disturbances; column 0 is T_amb. [°C, …]
        t_rule : numpy.ndarray of shape (T+1,)
            T_rule(k|t). [°C]
        u_prev : float
            u(t−1). [°C]

        Returns
        -------
        lower, upper : numpy.ndarray of shape (T+1,)
            [°C]
        """
        s = self.settings
        lower, upper = t_rule - s.u_band, t_rule + s.u_band
        if s.objective != "states":
            return lower, upper
        t_amb = np.concatenate(
            [np.asarray(d_past, dtype=float)[-1:, 0], np.asarray(d_future, dtype=float)[:, 0]]
        )
        coldest = np.full_like(t_rule, np.min(y0) - s.state_margin_k)
        cap = np.maximum.reduce([t_rule, coldest, t_amb + s.cool_above_k])
        cap[t_amb < t_rule - s.heat_below_k] = np.inf  # heating whatever the decks ask
        # no lower than the rate limit (7) can reach from u(t−1): the problem stays feasible
        cap = np.maximum(cap, u_prev - s.du_max * np.arange(1, len(t_rule) + 1))
        return lower, np.minimum(upper, cap)

    def constant(self, c, y0, t_opt, u_prev) -> float:
        """The constant terms of J: ‖c − r‖² + ‖y(t) − T_opt(0) 1‖² + σ‖T_opt‖² + γ u(t−1)²."""
        s = self.settings
        r = np.repeat(t_opt[1:], NY)
        return float(
            np.sum((c - r) ** 2)
            + np.sum((y0 - t_opt[0]) ** 2)
            + s.sigma * np.sum(t_opt**2)
            + s.gamma * u_prev**2
        )


def _difference(n: int) -> np.ndarray:
    """D with (D u)_0 = u_0 and (D u)_k = u_k − u_{k−1}: the changes of J_Δu and (7)."""
    return np.eye(n) - np.eye(n, k=-1)


class DDPCProblem:
    """The production path: Eq. (10) as a condensed QP solved by OSQP.

    Built once per predictor and settings (see the module docstring); each :meth:`solve`
    updates only the vectors and warm-starts from the last solution.

    Parameters
    ----------
    predictor : MultistepPredictor
        A fitted predictor (its Ĥ is the model (3)).
    settings : OCPSettings, optional
        Weights and bounds (default: :class:`OCPSettings`).

    Raises
    ------
    RuntimeError
        If the predictor is not fitted.

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section III.C, Eq. (10).
    """

    def __init__(self, predictor: MultistepPredictor, settings: OCPSettings | None = None):
        import osqp

        self.settings = settings or OCPSettings()
        self._m = _Condensed(predictor, self.settings)
        s, G, T, R = self.settings, self._m.G, self._m.T, self._m.R
        n_u, n_e = T + 1, NY * T
        n_m = 0 if R is None else len(R)
        D = _difference(n_u)
        P_u = G.T @ G + s.sigma * np.eye(n_u) + s.gamma * D.T @ D
        blocks = [2.0 * P_u, 2.0 * s.tau * sp.eye(n_e)]
        if n_m:
            blocks.append(2.0 * s.margin_weight * sp.eye(n_m))
        P = sp.block_diag(blocks, format="csc")
        I_e, Z_ue, Z_um = sp.eye(n_e), sp.csc_matrix((n_u, n_e)), sp.csc_matrix((n_u, n_m))
        Z_em = sp.csc_matrix((n_e, n_m))
        rows = [
            sp.hstack([G, -I_e, Z_em]),  # comfort, upper: y − ε ≤ T_rule + T_max
            sp.hstack([G, I_e, Z_em]),  # comfort, lower: y + ε ≥ T_rule − T_max
            sp.hstack([sp.csc_matrix((n_e, n_u)), I_e, Z_em]),  # ε ≥ 0
            sp.hstack([sp.eye(n_u), Z_ue, Z_um]),  # |u − T_rule| ≤ u_band, the state rule
            sp.hstack([sp.csc_matrix(D), Z_ue, Z_um]),  # rate limits
        ]
        if n_m:
            I_m, Z_me = sp.eye(n_m), sp.csc_matrix((n_m, n_e))
            rows += [
                sp.hstack([sp.csc_matrix(R), Z_me, -I_m]),  # margin, upper: R u − ξ ≤ o + m
                sp.hstack([sp.csc_matrix(R), Z_me, I_m]),  # margin, lower: R u + ξ ≥ o − m
                sp.hstack([sp.csc_matrix((n_m, n_u + n_e)), I_m]),  # ξ ≥ 0
            ]
        A = sp.vstack(rows, format="csc")
        self._n = n_u + n_e + n_m
        self._P, self._D = P, D
        self._solver = osqp.OSQP()
        n_rows = A.shape[0]
        self._solver.setup(
            P=sp.triu(P, format="csc"),
            q=np.zeros(self._n),
            A=A,
            l=np.full(n_rows, -np.inf),
            u=np.full(n_rows, np.inf),
            verbose=False,
            eps_abs=1e-7,
            eps_rel=1e-7,
            polishing=True,
            warm_starting=True,
            time_limit=s.time_limit_s,
            max_iter=20000,
        )

    @property
    def rho(self) -> int:
        """Lead-in ρ of the predictor."""
        return self._m.rho

    @property
    def horizon(self) -> int:
        """Horizon T of the predictor."""
        return self._m.T

    def solve(self, y_past, u_past, d_past, d_future, t_rule, t_opt, u_prev) -> Solution:
        """Solve Eq. (10) for one time step.

        Parameters
        ----------
        y_past : array-like of shape (ρ, 3)
            Measured room temperatures at t−ρ+1 … t; the last is y(t) = y(0|t). [°C]
        u_past : array-like of shape (ρ−1, 1) or (ρ−1,)
            Setpoints applied at t−ρ+1 … t−1 (u(t) = u(0|t) is a decision). [°C]
        d_past : array-like of shape (ρ, 5)
            Measured disturbances [T_amb °C, Q_Gt W/m², Q_Gs W/m², P % of seats, V km/h] at
            t−ρ+1 … t.
        d_future : array-like of shape (T, 5)
            Forecast disturbances at t+1 … t+T, as ``d_past``.
        t_rule : array-like of shape (T+1,)
            T_rule(k|t) for k = 0 … T. [°C]
        t_opt : array-like of shape (T+1,)
            T_opt(k|t) for k = 0 … T. [°C]
        u_prev : float
            u(t−1), the setpoint applied over the last interval. [°C]

        Returns
        -------
        Solution
            The optimum; NaN arrays and a status other than ``"solved"`` when none was found.

        Raises
        ------
        ValueError
            If an array has the wrong shape or holds NaN or infinite values.
        """
        m, s = self._m, self.settings
        T = m.T
        c, y0, t_rule, t_opt, u_prev = m.data(
            y_past, u_past, d_past, d_future, t_rule, t_opt, u_prev
        )
        r = np.repeat(t_opt[1:], NY)
        rule3 = np.repeat(t_rule[1:], NY)
        b = np.zeros(T + 1)
        b[0] = u_prev
        n_u = T + 1
        q = np.zeros(self._n)
        q[:n_u] = 2.0 * (m.G.T @ (c - r) - s.sigma * t_opt - s.gamma * self._D.T @ b)
        u_lower, u_upper = m.setpoint_bounds(y0, d_past, d_future, t_rule, u_prev)
        inf = np.full(NY * T, np.inf)
        lower = [-inf, rule3 - s.t_max - c, np.zeros(NY * T), u_lower, b - s.du_max]
        upper = [rule3 + s.t_max - c, inf, inf, u_upper, b + s.du_max]
        if m.R is not None:
            o, inf_m = m.margin_offset(c, y0), np.full(len(m.R), np.inf)
            lower += [np.full(len(m.R), -np.inf), o - s.margin_k, np.zeros(len(m.R))]
            upper += [o + s.margin_k, inf_m, inf_m]
        self._solver.update(q=q, l=np.concatenate(lower), u=np.concatenate(upper))
        res = self._solver.solve(raise_error=False)
        status = "solved" if res.info.status == "solved" else str(res.info.status)
        x = np.asarray(res.x, dtype=float)
        # without an (approximate) optimum OSQP's x is an unfinished iterate or an
        # infeasibility certificate (~1e9): report no solution, as the reference does
        if res.info.status not in ("solved", "solved inaccurate"):
            x = np.full(self._n, np.nan)
        if x.shape != (self._n,) or not np.all(np.isfinite(x)):
            x = np.full(self._n, np.nan)
            status = status if status != "solved" else "no solution"
        u, eps = x[:n_u], x[n_u : n_u + NY * T]
        y = c + m.G @ u
        objective = float(0.5 * x @ (self._P @ x) + q @ x) + m.constant(c, y0, t_opt, u_prev)
        return Solution(
            u=u,
            y=y.reshape(T, NY),
            eps=eps.reshape(T, NY),
            objective=objective,
            status=status,
            solve_time_s=float(res.info.run_time),
            iterations=int(res.info.iter),
        )


class ReferenceProblem:
    """The readable cvxpy formulation of Eq. (10), the reference for :class:`DDPCProblem`.

    DPP-compliant, so cvxpy compiles it once; solved with Clarabel by default (an interior-point
    method: accurate).

    Parameters
    ----------
    predictor : MultistepPredictor
        A fitted predictor.
    settings : OCPSettings, optional
        Weights and bounds (default: :class:`OCPSettings`).
    rebuild : bool, default False
        Construct and compile the problem at every :meth:`solve` (the naive path, for the
        benchmark).
    solver : str, default "CLARABEL"
        The cvxpy solver.

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section III.C, Eq. (10).
    """

    def __init__(
        self,
        predictor: MultistepPredictor,
        settings: OCPSettings | None = None,
        *,
        rebuild: bool = False,
        solver: str = "CLARABEL",
    ):
        self.settings = settings or OCPSettings()
        self._m = _Condensed(predictor, self.settings)
        self.rebuild = rebuild
        self.solver = solver
        if not rebuild:
            self._problem, self._params, self._vars = self._build()

    def _build(self):
        import cvxpy as cp

        m, s = self._m, self.settings
        T = m.T
        u, y, eps = cp.Variable(T + 1), cp.Variable(NY * T), cp.Variable(NY * T)
        p = {
            "c": cp.Parameter(NY * T),
            "r": cp.Parameter(NY * T),
            "t_opt": cp.Parameter(T + 1),
            "rule3": cp.Parameter(NY * T),
            "u_lower": cp.Parameter(T + 1),
            "u_upper": cp.Parameter(T + 1),
            "u_prev": cp.Parameter(),
        }
        du = cp.hstack([u[0] - p["u_prev"], cp.diff(u)])
        cost = (
            cp.sum_squares(y - p["r"])
            + s.sigma * cp.sum_squares(u - p["t_opt"])
            + s.tau * cp.sum_squares(eps)
            + s.gamma * cp.sum_squares(du)
        )
        constraints = [
            y == p["c"] + m.G @ u,  # (3)
            y - p["rule3"] <= s.t_max + eps,  # (4)
            p["rule3"] - y <= s.t_max + eps,
            eps >= 0,  # (5)
            u >= p["u_lower"],  # (6), and the state rule for ``states``
            u <= p["u_upper"],
            cp.abs(du) <= s.du_max,  # (7)
        ]
        if s.objective == "margin":
            p["y0_mean"] = cp.Parameter()
            xi = cp.Variable(2 * T + 1)
            y_mean = cp.hstack([p["y0_mean"], cp.reshape(y, (T, NY), order="C") @ np.ones(NY) / NY])
            gap = cp.hstack([u - y_mean, u[:T] - y_mean[1:]])
            constraints += [cp.abs(gap) <= s.margin_k + xi, xi >= 0]
            cost = cost + s.margin_weight * cp.sum_squares(xi)
        problem = cp.Problem(cp.Minimize(cost), constraints)
        return problem, p, (u, y, eps)

    def solve(self, y_past, u_past, d_past, d_future, t_rule, t_opt, u_prev) -> Solution:
        """Solve Eq. (10) for one time step, as :meth:`DDPCProblem.solve`.

        Parameters, Returns and Raises are those of :meth:`DDPCProblem.solve`; the solution's
        ``iterations`` is 0 (cvxpy does not report it) and ``solve_time_s`` is the wall-clock
        time of cvxpy's solve.
        """
        import cvxpy as cp

        m, T = self._m, self._m.T
        c, y0, t_rule, t_opt, u_prev = m.data(
            y_past, u_past, d_past, d_future, t_rule, t_opt, u_prev
        )
        if self.rebuild:
            problem, p, (u, y, eps) = self._build()
        else:
            problem, p, (u, y, eps) = self._problem, self._params, self._vars
        p["c"].value = c
        p["r"].value = np.repeat(t_opt[1:], NY)
        p["t_opt"].value = t_opt
        p["rule3"].value = np.repeat(t_rule[1:], NY)
        p["u_lower"].value, p["u_upper"].value = m.setpoint_bounds(
            y0, d_past, d_future, t_rule, u_prev
        )
        p["u_prev"].value = u_prev
        if "y0_mean" in p:
            p["y0_mean"].value = float(np.mean(y0))
        t0 = time.perf_counter()
        try:
            problem.solve(solver=self.solver)
            status = problem.status
        except cp.SolverError as exc:
            status = f"solver error: {exc}"
        elapsed = time.perf_counter() - t0
        if status not in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE) or u.value is None:
            nan = np.full((T, NY), np.nan)
            return Solution(
                np.full(T + 1, np.nan), nan, nan.copy(), float("nan"), str(status), elapsed
            )
        # J_y's k = 0 term (the measured y(t)) is the one constant outside cvxpy's objective
        objective = float(problem.value) + float(np.sum((y0 - t_opt[0]) ** 2))
        return Solution(
            u=np.asarray(u.value, dtype=float),
            y=np.asarray(y.value, dtype=float).reshape(T, NY),
            eps=np.asarray(eps.value, dtype=float).reshape(T, NY),
            objective=objective,
            status="solved" if status == cp.OPTIMAL else str(status),
            solve_time_s=elapsed,
        )
