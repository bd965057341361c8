"""Sensitivities of a simulated face: how its skin points move per unit of each control, from the
implicit solver's own step (the inverse solve of :mod:`.inverse` reads them).

A converged backward Euler step ``x*(u)`` from a start State solves ``g(x; u) = 0`` (``g`` the
gradient of the step's incremental potential, :class:`~facewarp._src.physics.solvers.incremental.
IncrementalPotential`; ``u`` the 27 activations and the 2 jaw angles). Differentiating,

    H dx/du = -dg/du      (free nodes; fixed and held nodes follow their targets, dx_c/du = dtarget/du)

with ``H`` the step's Hessian at ``x*`` (the PSD one the host solver factorises: fixed rows and
columns the identity). :func:`step_sensitivity` factorises it once and back-substitutes one right
hand side per control (29); ``dg/du`` is a one-sided finite difference of the solver's gradient
kernels in ``u`` at fixed ``x`` (the stages prepared for the perturbed controls: muscle geometry and
springs, jaw targets and carry; the fixed nodes moved onto their new targets, so ``dg/du`` carries
the coupling ``H_fc dx_c/du`` too). The muscles' fibre cosine is taken at ``x*`` (the fixed point
the host solver ends on) and held, as within the solver's own solve.

The skin points (FDPs, head vertices) are affine in the node positions at a given jaw
(:func:`~facewarp._src.sim.readout.head_surface`: surface nodes written in, opening rims a linear
blend, the rest of the head and the rigid parts turned by the jaw): :class:`PointReadout` keeps
that linear map as a sparse matrix and the jaw's own part by a finite difference.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import InputError

__all__ = ["PointReadout", "resolve_points", "step_sensitivity"]

ACTIVATION_STEP = 1e-2
"""Finite-difference step of an activation in ``dg/du`` (one-sided, into [0, 1])."""
JAW_STEP = 2e-3
"""Finite-difference step of a jaw angle [rad] in ``dg/du`` and in the read-out."""


def resolve_points(fr, points) -> list[tuple]:
    """Point names as read-out specs: ``("head", face, bary)``, ``("part", name, face, bary)`` or
    ``("vertex", index)``.

    Args:
        fr: The face rig.
        points: FDP ids (``"2.1"``) or head vertex names ``"v<index>"`` (a sequence of str).

    Raises:
        InputError: not a sequence of names, a repeated name, or names this head lacks (all of them named).
    """
    if isinstance(points, (str, bytes)) or not hasattr(points, "__iter__"):
        raise InputError(f"points: expected a list of FDP ids or 'v<index>' names, got {type(points).__name__}")
    names = [str(p) for p in points]
    if not names:
        raise InputError("points: the list is empty")
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise InputError(f"points: named more than once: {', '.join(dup)}")
    ids = [str(k) for k in fr.fdp_ids]
    nv = len(fr.head_vertices)
    out, bad = [], []
    for n in names:
        if n in ids:
            i = ids.index(n)
            part = str(fr.fdp_part[i])
            f, b = int(fr.fdp_face[i]), np.asarray(fr.fdp_bary[i], np.float64)
            out.append(("head", f, b) if part == "head" else ("part", part, f, b))
        elif n[:1] == "v" and n[1:].isdigit() and int(n[1:]) < nv:
            out.append(("vertex", int(n[1:])))
        else:
            bad.append(n)
    if bad:
        shown = ", ".join(repr(b) for b in bad[:8]) + (f" and {len(bad) - 8} more" if len(bad) > 8 else "")
        raise InputError(f"points: not an FDP id or a head vertex 'v0'..'v{nv - 1}' of this head: {shown}")
    return out


class PointReadout:
    """Skin points of a face rig as a function of node positions and jaw angles, head frame.

    ``points(X, jaw) = P X + c(jaw)``: ``P`` (3K, 3p) sparse (surface nodes and opening rims),
    ``c`` the kinematic rest of the head and the rigid parts at the jaw angles.

    Args:
        fr: The face rig.
        points: Point names (:func:`resolve_points`).
    """

    def __init__(self, fr, points):
        import scipy.sparse as sp

        from ..sim.readout import surface_index

        self.fr = fr
        if isinstance(points, (str, bytes)) or not hasattr(points, "__iter__"):  # resolve_points says it, once listed
            raise InputError(f"points: expected a list of FDP ids or 'v<index>' names, got {type(points).__name__}")
        self.names = [str(p) for p in points]
        self.specs = resolve_points(fr, points)
        self.index = surface_index(fr)
        nv, nn = len(fr.head_vertices), len(fr.nodes)
        # A: head vertices <- node positions (the X-linear part of readout.head_surface)
        node, vertex = self.index
        rows, cols, vals = [vertex], [node], [np.ones(len(node))]
        A = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(nv, nn))
        if fr.opening_vertex is not None and len(fr.opening_vertex):
            ov, w, on = np.asarray(fr.opening_vertex), np.asarray(fr.opening_weight), np.asarray(fr.opening_node)
            keep = np.ones(nv)
            keep[ov] = 0.0  # a rim's row is the rim blend only (head_surface writes rims last)
            R = sp.csr_matrix((w.ravel(), (np.repeat(ov, w.shape[1]), on.ravel())), shape=(nv, nn))
            A = sp.diags(keep) @ A + R
        # B: points <- head vertices
        br, bc, bv = [], [], []
        for k, s in enumerate(self.specs):
            if s[0] == "head":
                br += [k] * 3
                bc += list(fr.head_faces[s[1]])
                bv += list(s[2])
            elif s[0] == "vertex":
                br.append(k)
                bc.append(s[1])
                bv.append(1.0)
        B = sp.csr_matrix((bv, (br, bc)), shape=(len(self.specs), nv))
        self._B = B
        PK = (B @ A).tocsr()  # (K, p) per coordinate
        self.P = sp.kron(PK, sp.identity(3), format="csr")  # (3K, 3p)

    @property
    def count(self) -> int:
        """K, the number of points."""
        return len(self.specs)

    def offset(self, jaw) -> np.ndarray:
        """c(jaw): the points at zero node positions [m], shape (K, 3), float64."""
        from ..sim.readout import head_surface

        fr = self.fr
        j = np.asarray(jaw, np.float64)
        V = head_surface(fr, np.zeros((len(fr.nodes), 3)), j, self.index)
        out = (self._B @ V).reshape(-1, 3)
        parts = {}
        for k, s in enumerate(self.specs):
            if s[0] == "part":
                if s[1] not in parts:
                    parts[s[1]] = fr.part_at(s[1], j)
                out[k] = s[3] @ parts[s[1]][fr.parts[s[1]][1][s[2]]]
        return out

    def points(self, X, jaw) -> np.ndarray:
        """The points [m], shape (K, 3), float64, at node positions X (p, 3) [m] and jaw (2,) [rad] (head frame)."""
        return (self.P @ np.asarray(X, np.float64).ravel()).reshape(-1, 3) + self.offset(jaw)

    def jacobian(self, dX, jaw) -> np.ndarray:
        """dp/du (3K, C) from dx/du ``dX`` (C, p, 3) and the read-out's own jaw part (the last two
        controls are the jaw angles), at ``jaw`` (2,) [rad]."""
        C = dX.shape[0]
        J = (self.P @ dX.reshape(C, -1).T)
        c0 = self.offset(jaw).ravel()
        for i in range(2):
            j = np.array(jaw, np.float64)
            step = JAW_STEP if not (i == 0 and j[0] + JAW_STEP > _jaw_max()[0]) else -JAW_STEP
            j[i] += step
            J[:, C - 2 + i] += (self.offset(j).ravel() - c0) / step
        return J


def _jaw_max():
    from ..expressions import JAW_U_MAX, JAW_V_MAX

    return JAW_U_MAX, JAW_V_MAX


def _factorize(A, backend: str):
    from ..physics.solvers.host_implicit import _factorize as factor

    return factor(A, backend)


def step_sensitivity(sim, start, activations, jaw, X, *, solve=None, corrections: int = 0) -> np.ndarray:
    """dx/du of one implicit step of ``sim`` from the State ``start`` to its solution ``X`` at the
    controls (``activations``, ``jaw``) (module doc).

    Args:
        sim: The :class:`~facewarp.FaceSimulator` (implicit solver).
        start: The step's start, a State of ``sim.model`` (read, not changed).
        activations: (M,) the step's activations; jaw: (2,) [rad] its jaw angles.
        X: The step's solution [m], (p, 3) float64 (the simulator's positions after the step).
        solve: A factorisation of the step's Hessian to reuse (``b -> H^-1 b``); default: made here.
        corrections: Iterations towards the exact tangent: the PSD Hessian lacks the negative
            curvature of the element energies, so each correction takes the gradient's finite
            difference along the current ``(dx/du, e_u)`` and back-substitutes its residual again.

    Returns:
        ``(dX, solve)``: dX (M + 2, p, 3) float64 [m per unit activation, m per rad], and the
        factorisation used.

    The solver's control, targets and scratch buffers are restored (the simulator's State is not touched).
    """
    from ..core.warp import get_warp

    wp = get_warp()
    solver, model = sim.solver, sim.model
    if not hasattr(solver, "incremental"):
        raise InputError(f"sim: the inverse solve needs the implicit solver, got solver={sim.solver_name!r}")
    ip = solver.incremental
    h = float(sim.dt)
    a0 = np.asarray(activations, np.float32)
    j0 = np.asarray(jaw, np.float32)
    u0 = np.concatenate([a0, j0]).astype(np.float64)
    M = len(a0)
    fixed = model.vertex_fixed.numpy() != 0
    saved_targets = wp.clone(solver.targets)
    saved_a, saved_j = wp.clone(sim.control.activations), wp.clone(sim.control.jaw_angles)
    scratch = _scratch_state(sim)
    X = np.asarray(X, np.float64)

    def grad_at(u, X=X):
        scratch.assign(start)
        sim.control.activations.assign(u[:M].astype(np.float32))
        sim.control.jaw_angles.assign(u[M:].astype(np.float32))
        solver._begin(scratch, sim.control, h)
        x = X.copy()
        x[fixed] = solver.targets.numpy()[fixed]
        ip.x.assign(x.astype(np.float32))
        for st in solver._refreshers:
            st.refresh(model, ip.x, sim.control)
        ip.launch_energy(ip.x, sim.control, h)
        g = ip.grad.numpy().astype(np.float64)
        g[fixed] = 0.0
        return g, x

    try:
        g0, x0 = grad_at(u0)
        if solve is None:
            ip.launch_hessian(ip.x, h, 0.0)
            solve = _factorize(ip.hessian_matrix(), getattr(solver, "backend", "splu"))
        umax = np.r_[np.ones(M), _jaw_max()]
        dX = np.zeros((M + 2, len(X), 3))
        for i in range(M + 2):
            step = ACTIVATION_STEP if i < M else JAW_STEP
            if u0[i] + step > umax[i]:  # one-sided into the range (the activation curve is clamped at 0 and 1)
                step = -step
            u = u0.copy()
            u[i] += step
            g, x = grad_at(u)
            dg = (g - g0) / step
            d = -np.asarray(solve(dg.ravel())).reshape(-1, 3)
            d[fixed] = (x[fixed] - x0[fixed]) / step
            if corrections:  # towards the exact tangent: H_psd preconditions the true dg/dx
                d = _correct(lambda v: (grad_at(u, X + step * v)[0] - g0) / step, solve, d, fixed, corrections)
            dX[i] = d
    finally:
        wp.copy(solver.targets, saved_targets)
        wp.copy(sim.control.activations, saved_a)
        wp.copy(sim.control.jaw_angles, saved_j)
    return dX, solve


def _correct(residual, solve, d, fixed, corrections: int) -> np.ndarray:
    """Preconditioned fixed-point iterations ``d <- d - H^-1 r(d)`` on the tangent equation's residual
    ``r(d)`` (the gradient's change along ``(d, e_u)``), keeping the ``d`` of the smallest residual
    (the PSD Hessian may over-correct a soft mode: an iteration that does not lower it ends them)."""
    best, r_best = d, None
    for k in range(corrections + 1):
        r = residual(d)
        r[fixed] = 0.0
        nr = float(np.linalg.norm(r))
        if r_best is not None and not nr < r_best:
            return best
        best, r_best = d, nr
        if k == corrections:
            break
        dd = -np.asarray(solve(r.ravel())).reshape(-1, 3)
        dd[fixed] = 0.0
        d = d + dd
    return best


def _scratch_state(sim):
    """A State of ``sim.model`` kept on the simulator for the sensitivities (made once)."""
    st = getattr(sim, "_sensitivity_scratch", None)
    if st is None:
        st = sim.model.state()
        sim._sensitivity_scratch = st
    return st
