"""What the workbench shows about a design, computed from engine objects (no Textual).

- :func:`plant_report`: the derived Jacobian, the linearisation at the operating point, the
  discretised model, eigenvalues and controllability, as text;
- :func:`mpc_preview`: a short closed loop of the *online* MPC on the prediction model, to
  judge a tuning before paying for explicit synthesis;
- :func:`region_rows` / :func:`locate_state`: the synthesis screen's table and state lookup.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from codev_engine import ExplicitLaw, LinearModel, Problem

__all__ = [
    "MpcPreview",
    "locate_state",
    "mpc_preview",
    "plant_report",
    "region_rows",
    "shared_laws",
]


def _fmt(M: np.ndarray, indent: str = "  ") -> str:
    M = np.atleast_2d(np.asarray(M, dtype=float))
    cells = [[f"{v:.6g}" for v in row] for row in M]
    w = max((len(c) for row in cells for c in row), default=1)
    return "\n".join(indent + "[ " + "  ".join(c.rjust(w) for c in row) + " ]" for row in cells)


def _eig(M: np.ndarray) -> str:
    ev = np.linalg.eigvals(np.asarray(M, dtype=float))
    ev = ev[np.lexsort((ev.imag, ev.real))]
    parts = []
    for v in ev:
        if abs(v.imag) <= 1e-12 * max(1.0, abs(v)):
            parts.append(f"{v.real:.6g}")
        else:
            parts.append(f"{v.real:.6g}{v.imag:+.6g}j")
    return ", ".join(parts)


def plant_report(problem: Problem) -> tuple[str, LinearModel]:
    """The plant screen's derived view of a problem.

    Parameters
    ----------
    problem : Problem
        A valid spec (its plant and model sections are used).

    Returns
    -------
    text : str
        Markdown: symbolic Jacobians, ``Ac``, ``Bc``, ``f(x_op, u_op)``, the discrete ``A``,
        ``B``, ``c``, eigenvalues (continuous and discrete, with stability), the
        controllability matrix's rank.
    model : LinearModel
        The discretised model the text describes.
    """
    from codev_engine import discretize
    from codev_engine.plant import symbolic_model

    model = discretize(problem)
    plant, ms = problem.plant, problem.model
    out: list[str] = []
    if plant.dynamics is not None or plant.A is not None:
        from sympy import sstr

        def expr(e) -> str:  # -0.5, not -0.500000000000000
            return sstr(e, full_prec=False)

        sym = symbolic_model(problem)
        out.append("### Jacobian of f at (x, u)\n")
        out.append("```")
        for i, s in enumerate(plant.states):
            row_x = ", ".join(expr(sym.Jx[i, j]) for j in range(plant.n))
            row_u = ", ".join(expr(sym.Ju[i, j]) for j in range(plant.m))
            out.append(f"d f_{s}:  ∂/∂x = [{row_x}]   ∂/∂u = [{row_u}]")
        out.append("```")
    op = ", ".join(f"{s}={v:.4g}" for s, v in zip(plant.states, ms.x_op, strict=True))
    opu = ", ".join(f"{s}={v:.4g}" for s, v in zip(plant.inputs, ms.u_op, strict=True))
    out.append(f"\n### Linearisation at x = ({op}), u = ({opu})\n")
    out.append("```")
    if model.Ac is not None:
        out += ["Ac =", _fmt(model.Ac), "Bc =", _fmt(model.Bc)]
        out.append(
            f"eig(Ac) = {_eig(model.Ac)}"
            + (
                "   (stable)"
                if np.all(np.linalg.eigvals(model.Ac).real < 0)
                else "   (not asymptotically stable)"
            )
        )
    else:
        out.append("explicit discrete model: no continuous linearisation")
    out.append("```")
    out.append(
        f"\n### Discretised ({ms.method if model.Ac is not None else 'given'}, "
        f"dt = {model.dt:g} s): dx+ = A dx + B du + c\n"
    )
    out.append("```")
    out += ["A =", _fmt(model.A), "B =", _fmt(model.B)]
    if np.any(model.c != 0):
        out += ["c =", _fmt(model.c[None, :]), "(the operating point is not an equilibrium)"]
    rho = float(np.max(np.abs(np.linalg.eigvals(model.A))))
    out.append(
        f"eig(A)  = {_eig(model.A)}   spectral radius {rho:.6g}"
        + ("  (stable)" if rho < 1 else "  (open loop not stable)")
    )
    n = model.n
    ctrb = np.hstack([np.linalg.matrix_power(model.A, k) @ model.B for k in range(n)])
    rank = int(np.linalg.matrix_rank(ctrb))
    out.append(
        f"controllability rank {rank} of {n}"
        + ("  (controllable)" if rank == n else "  (NOT controllable)")
    )
    out.append("```")
    return "\n".join(out), model


@dataclass(frozen=True)
class MpcPreview:
    """A closed loop of the online MPC on the prediction model.

    Attributes
    ----------
    t : (K+1,) ndarray
        Sample times.
    X : (K+1, n) ndarray
        States (plant coordinates).
    U : (K, m) ndarray
        Applied inputs.
    infeasible_at : int or None
        The step at which the MPC became infeasible (the loop stops there).
    seconds : float
    reference : (p,) ndarray or None
        The reference the loop followed, when the law takes one as a parameter (a
        ``[mpc.reference]`` box); a fixed reference is the spec's own.
    u_prev0 : (m,) ndarray or None
        The input held before the first sample, when the law takes ``u_prev`` (rates).
    """

    t: np.ndarray
    X: np.ndarray
    U: np.ndarray
    infeasible_at: int | None
    seconds: float
    reference: np.ndarray | None = None
    u_prev0: np.ndarray | None = None


def preview_extras(problem: Problem) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The default ``u_prev`` and reference of a preview, for a law that takes them.

    Parameters
    ----------
    problem : Problem

    Returns
    -------
    u_prev : (m,) ndarray or None
        With input rates: the middle of ``[verify] initial_input``, else the operating
        input; None without rates.
    reference : (p,) ndarray or None
        With a reference box: the middle of ``[verify] reference``, else of the
        ``[mpc.reference]`` box; None otherwise.
    """
    spec, v = problem.mpc, problem.verify
    rates = any(
        a is not None for a in (getattr(spec, "du_min", None), getattr(spec, "du_max", None),
                                getattr(spec, "Rd", None))
    )
    u_prev = None
    if rates:
        if v is not None and v.initial_input_lower is not None:
            u_prev = 0.5 * (v.initial_input_lower + v.initial_input_upper)
        else:
            u_prev = np.asarray(problem.model.u_op, dtype=float)
    ref = spec.reference
    r = None
    if ref is not None and ref.lower is not None:
        if v is not None and v.reference_lower is not None:
            r = 0.5 * (v.reference_lower + v.reference_upper)
        else:
            r = 0.5 * (np.asarray(ref.lower, float) + np.asarray(ref.upper, float))
    return u_prev, r


def mpc_preview(
    problem: Problem,
    model: LinearModel,
    x0: np.ndarray,
    steps: int,
    should_stop=lambda: False,
    *,
    reference: np.ndarray | None = None,
) -> MpcPreview:
    """Simulate ``steps`` samples of the online MPC (cvxpy + Clarabel) from ``x0``.

    The loop runs on the discrete prediction model ``dx+ = A dx + B du + c`` (what the MPC
    believes), not the nonlinear plant: the verification stage covers the true plant.

    Parameters
    ----------
    problem : Problem
        The spec (its ``mpc`` section is the MPC solved).
    model : LinearModel
        The prediction model, ``discretize(problem)``.
    x0 : (n,) array_like of float
        The initial state (plant coordinates).
    steps : int
        The number of samples simulated.
    should_stop : callable
        Called before each step with no argument; True stops the loop there (the
        workbench's cancel).
    reference : (p,) array_like, optional
        The reference to follow, for a law over a reference box (default: see
        :func:`preview_extras`); a law with input rates starts from the ``u_prev`` of
        :func:`preview_extras` and then holds the input it applied.

    Returns
    -------
    MpcPreview
        The loop up to ``steps``, the first infeasible step, or the stop.
    """
    import time

    from codev_engine import OnlineMpc

    t0 = time.perf_counter()
    mpc = OnlineMpc(problem.mpc, model)
    fm = mpc.formulation
    u_prev, r = preview_extras(problem)
    if reference is not None and fm.nr:
        r = np.asarray(reference, dtype=float).reshape(fm.nr)
    u_prev = u_prev if fm.rates else None
    r = r if fm.nr else None
    u_prev0 = None if u_prev is None else np.array(u_prev, dtype=float)
    x = np.asarray(x0, dtype=float).reshape(model.n)
    X, U = [x.copy()], []
    stop = None
    for k in range(int(steps)):
        if should_stop():
            break
        # θ = (x, u_prev, r): the law's own loop holds the input it applied
        theta = np.concatenate([x] + [v for v in (u_prev, r) if v is not None])
        sol = mpc.solve(theta)
        if not sol.feasible:
            stop = k
            break
        u = sol.u0
        if u_prev is not None:
            u_prev = np.array(u, dtype=float)
        dx = model.A @ (x - model.x_op) + model.B @ (u - model.u_op) + model.c
        x = model.x_op + dx
        X.append(x.copy())
        U.append(u.copy())
    Xa = np.array(X)
    Ua = np.array(U).reshape(len(U), model.m)
    t = np.arange(Xa.shape[0]) * model.dt
    return MpcPreview(t, Xa, Ua, stop, time.perf_counter() - t0, r, u_prev0)


def preview_signals(
    problem: Problem, prev: MpcPreview
) -> tuple[np.ndarray, tuple[str, ...], list[tuple[str, float]]]:
    """What the preview's state plot draws: the states, the outputs that are not a state
    themselves, and the reference the loop followed.

    Parameters
    ----------
    problem : Problem
        The spec previewed.
    prev : MpcPreview

    Returns
    -------
    Y : (K+1, q) ndarray
        The states, then each output ``y<i> = C x`` whose row of ``C`` is not a unit vector.
    labels : tuple of str
        Their names (q).
    lines : list of (str, float)
        The reference, one horizontal line per followed signal: ``("r <name>", value)``,
        named by the state an output row picks (``r angle`` for ``C = [[1, 0]]``). The value
        is the reference followed (typed or :func:`preview_extras`'s) or the fixed one.
    """
    mpc = problem.mpc
    states = tuple(problem.plant.states)
    Y, labels = np.asarray(prev.X, dtype=float), states
    C = None if mpc.C is None else np.asarray(mpc.C, dtype=float)
    output_as: list[str] = []  # the name each output is drawn under
    if C is not None:
        extra = []
        for k, row in enumerate(C):
            picks = np.flatnonzero(row)
            if picks.size == 1 and row[picks[0]] == 1.0:
                output_as.append(states[picks[0]])
            else:
                output_as.append(f"y{k}")
                extra.append(k)
        if extra:
            Y = np.hstack([Y, Y[:, : C.shape[1]] @ C[extra].T])
            labels = labels + tuple(f"y{k}" for k in extra)
    ref = mpc.reference
    if ref is None:
        return Y, labels, []
    if prev.reference is not None:
        r = np.asarray(prev.reference, dtype=float)
    elif ref.value is not None:
        r = np.asarray(ref.value, dtype=float)
    else:
        r = preview_extras(problem)[1]
    names = states if ref.signal == "x" else tuple(output_as)
    return Y, labels, [(f"r {nm}", float(v)) for nm, v in zip(names, r, strict=True)]


def region_rows(law: ExplicitLaw, limit: int = 500) -> list[tuple[str, ...]]:
    """Rows of the synthesis screen's region table, one per critical region.

    Parameters
    ----------
    law : ExplicitLaw
    limit : int
        At most this many rows (the first regions).

    Returns
    -------
    list of tuple of str
        ``(index, number of facets, the law u = F x + G, the bounding box)`` per region.
    """
    rows = []
    names = law.parameter_names or tuple(f"x{k}" for k in range(law.n))
    lo, hi = law.boxes
    # bounds that are rounding next to the partition's size show as 0 (an LP's vertex at
    # 5.55e-17 for a corner at 0)
    tiny = 1e-12 * max(1.0, float(np.max(np.abs(np.r_[lo.ravel(), hi.ravel()]), initial=0.0)))

    def bound(v: float) -> str:
        return f"{0.0 if abs(v) <= tiny else v:.3g}"

    for k in range(min(law.num_regions, limit)):
        F, G = law.F[k], law.G[k]
        laws = []
        for i in range(law.m):
            # coefficients within a relative 1e-12 of the row's largest are round-off: 0
            # (a saturated region reads +1, not -1.665e-16·p +6.661e-16·v +1)
            big = max(float(np.max(np.abs(F[i]), initial=0.0)), abs(float(G[i])))
            cut = 1e-12 * big
            terms = " ".join(
                f"{F[i, j]:+.4g}·{names[j]}" for j in range(law.n) if abs(F[i, j]) > cut
            )
            g = float(G[i]) if abs(G[i]) > cut else 0.0
            laws.append((terms + f" {g:+.4g}").strip())
        box = " × ".join(f"[{bound(a)}, {bound(b)}]" for a, b in zip(lo[k], hi[k], strict=True))
        rows.append((str(k), str(len(law.b[k])), "; ".join(laws), box))
    return rows


def shared_laws(law: ExplicitLaw, rtol: float = 1e-9) -> int:
    """How many regions could go: regions whose affine law equals another region's.

    Parameters
    ----------
    law : ExplicitLaw
    rtol : float
        Laws equal up to this relative round-off (of the largest coefficient) count as one.

    Returns
    -------
    int
        ``num_regions`` minus the number of distinct laws (0: every law is its own).
    """
    if law.num_regions < 2:
        return 0
    FG = np.concatenate(
        [
            np.asarray(law.F).reshape(law.num_regions, -1),
            np.asarray(law.G).reshape(law.num_regions, -1),
        ],
        axis=1,
    )
    scale = max(float(np.max(np.abs(FG), initial=0.0)), 1e-300)
    keys = np.round(FG / (scale * rtol)).astype(np.int64)
    return law.num_regions - int(np.unique(keys, axis=0).shape[0])


def locate_state(law: ExplicitLaw, x: np.ndarray) -> tuple[int, np.ndarray | None]:
    """The critical region of one state and the law's input there.

    Parameters
    ----------
    law : ExplicitLaw
    x : (n,) array_like of float
        The state.

    Returns
    -------
    region : int
        The region's index, or -1 outside the law's domain (where the MPC is infeasible).
    u : (m,) ndarray or None
        The input ``F x + G`` of that region; None outside the domain.
    """
    x = np.asarray(x, dtype=float).reshape(1, law.n)
    k = int(law.locate(x)[0])
    if k < 0:
        return -1, None
    return k, law.evaluate(x)[0]
