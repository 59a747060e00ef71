"""RMP² in pure JAX: pullback of leaf RMPs through a task map and the root resolve.

Thesis §3.2.2 (Algorithm 2, eqs 3.7–3.12), the natural-form closed solution (3.31) and the
first-order (velocity) form of chapter 5 (eq 5.1).

A *task map* ``task_map(q, *ctx)`` returns a pytree whose leaves are arrays shaped ``(n_k, m_k)``:
a family of ``n_k`` subtasks of dimension ``m_k`` each (e.g. 48 control points in 3-D, or
144 point–obstacle distances in 1-D). A *leaf function* ``leaf_fn(x_tree, xd_tree, *ctx)``
returns a pytree of the same structure whose leaves are :class:`~mjxrmp.core.rmp.RMP`
``(M (n,m,m), f (n,m))``.

Velocities ``ẋ = J q̇`` and curvatures ``c = J̇ q̇`` come from two nested forward-mode JVPs
(eq 3.11); the Jacobians of every family come from ``d`` forward tangents evaluated together with
``vmap`` (``d ≤ 7``), so no per-leaf Python loop exists anywhere. The root is
``M = Σ Jᵀ M_k J`` and ``f = Σ Jᵀ (f_k − M_k c_k)`` (eq 3.31).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from jax.experimental import checkify

from mjxrmp.core.linalg import spd_solve
from mjxrmp.core.rmp import RMP

TaskMap = Callable[..., Any]
LeafFn = Callable[..., Any]

#: Root regularisation of the original implementation: ``M ← M/scale + 1e-3·I``.
RESOLVE_REGULARIZATION = 1e-3
#: ``scale = max(1, RESOLVE_SCALE · max|M_ij|)``.
RESOLVE_SCALE = 0.01
#: Debug mode accepts a leaf metric eigenvalue down to ``−PSD_TOLERANCE · eps · max|M_ij|``
#: (rounding of a singular metric such as a rank-one target metric).
PSD_TOLERANCE = 100.0


# --------------------------------------------------------------------------------------------
# Validation at the Python boundary (shapes are static, so this also runs while tracing).
# --------------------------------------------------------------------------------------------


def check_configuration(name: str, value: Any, d: int | None = None) -> jax.Array:
    """``value`` as a 1-D floating configuration (of length ``d`` if given), else a clear error."""
    arr = jnp.asarray(value) if not isinstance(value, jax.Array) else value
    if arr.ndim != 1:
        raise ValueError(
            f"{name} must be a 1-D configuration vector of shape (d,), got shape {arr.shape}; "
            "batch with jax.vmap instead of passing a batch"
        )
    if arr.shape[0] == 0:
        raise ValueError(f"{name} must have at least one coordinate, got shape {arr.shape}")
    if not jnp.issubdtype(arr.dtype, jnp.floating):
        raise TypeError(f"{name} must be a floating-point array, got dtype {arr.dtype}")
    if d is not None and arr.shape[0] != d:
        raise ValueError(f"{name} must have shape ({d},) to match q, got {arr.shape}")
    return arr


def check_task_tree(x_tree: Any) -> None:
    """Raise unless ``x_tree`` is a non-empty pytree of ``(n_k, m_k)`` arrays (or shapes)."""
    leaves, _ = jax.tree_util.tree_flatten_with_path(x_tree)
    if not leaves:
        raise ValueError("task_map returned an empty pytree; it must return at least one leaf")
    for path, leaf in leaves:
        where = jax.tree_util.keystr(path) or "<root>"
        if not hasattr(leaf, "shape") or not hasattr(leaf, "dtype"):
            raise TypeError(
                f"task_map must return a pytree of arrays; got {type(leaf).__name__} at {where}"
            )
        if leaf.ndim != 2:
            raise ValueError(
                f"task_map leaf {where} must have shape (n_k, m_k) (a family of n_k subtasks of "
                f"dimension m_k), got shape {leaf.shape}"
            )


def flatten_leaf_rmps(x_tree: Any, rmps: Any, second: str) -> list[RMP]:
    """Flatten ``leaf_fn``'s output up to the task map's structure, checking every leaf."""
    x_struct = jax.tree.structure(x_tree)
    paths = [jax.tree_util.keystr(p) or "<root>" for p, _ in
             jax.tree_util.tree_flatten_with_path(x_tree)[0]]
    try:
        nodes = x_struct.flatten_up_to(rmps)
    except (ValueError, TypeError) as err:
        raise ValueError(
            "leaf_fn must return a pytree with the same structure as task_map's output "
            f"({x_struct}) whose leaves are RMP(M, {second}); got {type(rmps).__name__}: {err}"
        ) from None
    x_leaves = jax.tree.leaves(x_tree)
    out = []
    for where, node, x in zip(paths, nodes, x_leaves, strict=True):
        if not isinstance(node, RMP):
            raise TypeError(
                f"leaf_fn must return RMP(M, {second}) at {where}, got {type(node).__name__}"
            )
        n, m = x.shape
        M, f = node
        if not hasattr(M, "shape") or M.shape != (n, m, m):
            raise ValueError(
                f"leaf_fn RMP at {where}: M must have shape {(n, m, m)}, "
                f"got {getattr(M, 'shape', type(M).__name__)}"
            )
        if not hasattr(f, "shape") or f.shape != (n, m):
            raise ValueError(
                f"leaf_fn RMP at {where}: {second} must have shape {(n, m)}, "
                f"got {getattr(f, 'shape', type(f).__name__)}"
            )
        out.append(node)
    return out


def _check_root(root: Any) -> tuple[jax.Array, jax.Array]:
    if not isinstance(root, RMP) and not (isinstance(root, tuple) and len(root) == 2):
        raise TypeError(f"root must be RMP(M, f), got {type(root).__name__}")
    M, f = root
    if M.ndim != 2 or M.shape[0] != M.shape[1]:
        raise ValueError(f"root.M must be a square (d, d) matrix, got shape {M.shape}")
    if f.shape != (M.shape[0],):
        raise ValueError(f"root.f must have shape ({M.shape[0]},) to match root.M, got {f.shape}")
    return M, f


def _debug_check(enabled: bool, tree: Any, what: str) -> None:
    if not enabled:
        return
    for path, leaf in jax.tree_util.tree_flatten_with_path(tree)[0]:
        where = jax.tree_util.keystr(path)
        checkify.check(jnp.all(jnp.isfinite(leaf)), f"non-finite value in {what}{where}")


def _debug_check_metrics(enabled: bool, x_tree: Any, rmps: list[RMP]) -> None:
    """Debug mode: every leaf metric ``M_k`` must be positive semi-definite (thesis §3.2.2: a
    leaf with ``ẋᵀM_kẋ < 0`` reverses its own acceleration in the root). The quadratic form
    sees only the symmetric part, and ``M = G + Ξ_G`` of a velocity-dependent metric (eq 3.14)
    need not be symmetric, so the check is ``λ_min(½(M + Mᵀ)) ≥ −tol·max|M|`` per member."""
    if not enabled:
        return
    paths = [jax.tree_util.keystr(p) or "<root>" for p, _ in
             jax.tree_util.tree_flatten_with_path(x_tree)[0]]
    for where, (M, _) in zip(paths, rmps, strict=True):
        if M.shape[0] == 0:
            continue
        M = jnp.where(jnp.isfinite(M), M, 0.0)  # non-finite entries: reported by _debug_check
        sym = 0.5 * (M + jnp.swapaxes(M, -1, -2))
        low = sym[:, 0, 0] if M.shape[-1] == 1 else jnp.linalg.eigvalsh(sym)[:, 0]
        tol = PSD_TOLERANCE * jnp.finfo(M.dtype).eps * jnp.max(jnp.abs(M), axis=(1, 2))
        ok = low >= -tol
        first = jnp.argmin(ok)
        name = where.replace("{", "{{").replace("}", "}}")
        checkify.check(jnp.all(ok), f"leaf_fn output{name}: metric M is not positive "
                       "semi-definite; member {member} has minimum eigenvalue {value}",
                       member=first, value=low[first])


# --------------------------------------------------------------------------------------------
# Forward pass: positions, velocities, curvatures and Jacobians of every family.
# --------------------------------------------------------------------------------------------


def task_kinematics(task_map: TaskMap, q: jax.Array, qd: jax.Array, *ctx: Any
                    ) -> tuple[Any, Any, Any, Any]:
    """Subtask positions ``x``, velocities ``ẋ = J q̇`` and curvatures ``c = J̇ q̇`` (eq 3.11).

    Returns ``(x, xd, c, J)``, four pytrees with the task map's structure; ``J`` leaves have shape
    ``(n_k, m_k, d)``.
    """
    fn = lambda q_: task_map(q_, *ctx)  # noqa: E731

    def position_and_velocity(q_):
        return jax.jvp(fn, (q_,), (qd,))

    (x, xd), (_, c) = jax.jvp(position_and_velocity, (q,), (qd,))
    basis = jnp.eye(q.shape[0], dtype=q.dtype)
    J = jax.vmap(lambda v: jax.jvp(fn, (q,), (v,))[1], out_axes=-1)(basis)
    return x, xd, c, J


def task_jacobian(task_map: TaskMap, q: jax.Array, *ctx: Any) -> tuple[Any, Any]:
    """Subtask positions and Jacobians ``(x, J)`` (first-order forward pass of eq 5.1)."""
    fn = lambda q_: task_map(q_, *ctx)  # noqa: E731
    x = fn(q)
    basis = jnp.eye(q.shape[0], dtype=q.dtype)
    J = jax.vmap(lambda v: jax.jvp(fn, (q,), (v,))[1], out_axes=-1)(basis)
    return x, J


def _accumulate(J_leaves, rmps: list[RMP], c_leaves=None) -> RMP:
    """``M = Σ Jᵀ M_k J`` and ``f = Σ Jᵀ (f_k − M_k c_k)`` over families (eq 3.31).

    Families of equal subtask dimension are concatenated first, so each dimension costs one
    contraction however many families share it; scalar families (collision distances, joint
    limits, velocity caps) reduce to ``(w ⊙ J)ᵀ J``. The contractions are broadcast products and
    sums rather than matrix products: subtask dimensions are tiny (m ≤ 7), so XLA fuses them with
    their producers into a few kernels — no batched tiny GEMMs and no TF32 rounding on GPUs
    (2.8e7 vs 1.9e7 Franka evaluations/s on an H100), and fewer kernels on a CPU.
    """
    groups: dict[int, list[tuple[jax.Array, jax.Array, jax.Array]]] = {}
    for i, (J, (M, f)) in enumerate(zip(J_leaves, rmps, strict=True)):
        if c_leaves is not None:
            f = f - jnp.sum(M * c_leaves[i][:, None, :], axis=-1)
        groups.setdefault(J.shape[1], []).append((J, M, f))
    M_root = 0.0
    f_root = 0.0
    for m, members in sorted(groups.items()):
        J, M, f = (jnp.concatenate(parts, axis=0) for parts in zip(*members, strict=True))
        if m == 1:
            J1 = J[:, 0, :]
            M_root = M_root + jnp.sum((J1 * M[:, 0, 0, None])[:, :, None] * J1[:, None, :], axis=0)
        else:
            MJ = jnp.sum(M[:, :, :, None] * J[:, None, :, :], axis=2)  # (n, m, d)
            M_root = M_root + jnp.sum(J[:, :, :, None] * MJ[:, :, None, :], axis=(0, 1))
        f_root = f_root + jnp.sum(J * f[:, :, None], axis=(0, 1))
    return RMP(M_root, f_root)


def _pullback(task_map, leaf_fn, q, qd, ctx, debug: bool) -> RMP:
    x, xd, c, J = task_kinematics(task_map, q, qd, *ctx)
    check_task_tree(x)
    _debug_check(debug, (x, xd, c, J), "task_map output (x, xd, curvature, J)")
    rmps = flatten_leaf_rmps(x, leaf_fn(x, xd, *ctx), "f")
    _debug_check(debug, jax.tree.unflatten(jax.tree.structure(x), rmps), "leaf_fn output")
    _debug_check_metrics(debug, x, rmps)
    root = _accumulate(jax.tree.leaves(J), rmps, jax.tree.leaves(c))
    _debug_check(debug, root, "root RMP")
    return root


def _pullback_velocity(task_map, leaf_fn, q, ctx, debug: bool) -> RMP:
    x, J = task_jacobian(task_map, q, *ctx)
    check_task_tree(x)
    _debug_check(debug, (x, J), "task_map output (x, J)")
    rmps = flatten_leaf_rmps(x, leaf_fn(x, *ctx), "p")
    _debug_check(debug, jax.tree.unflatten(jax.tree.structure(x), rmps), "leaf_fn output")
    _debug_check_metrics(debug, x, rmps)
    root = _accumulate(jax.tree.leaves(J), rmps)
    _debug_check(debug, root, "root RMP")
    return root


def _resolve(root: RMP) -> jax.Array:
    M, f = _check_root(root)
    scale = jnp.maximum(1.0, RESOLVE_SCALE * jnp.max(jnp.abs(M)))
    M = M / scale + RESOLVE_REGULARIZATION * jnp.eye(M.shape[0], dtype=M.dtype)
    return spd_solve(M, f / scale)


def _run_debug(fn: Callable[..., jax.Array], args: tuple) -> jax.Array:
    """Run ``fn(*args)`` under checkify (named checks + float checks), compiled; raise a named
    error (with the first NaN-making operation, if any) before a float error.

    The inputs are traced arguments (not closed-over constants) so that every operation that
    depends on them is checked.
    """
    if any(isinstance(a, jax.core.Tracer) for a in jax.tree.leaves(args)):
        raise ValueError(
            "debug=True needs concrete inputs (it raises eagerly); inside jit/vmap, wrap your "
            "own function with jax.experimental.checkify instead"
        )
    names = ("q", "qd", "ctx") if len(args) == 3 else ("q", "ctx")
    for name, arg in zip(names, args, strict=True):
        for path, leaf in jax.tree_util.tree_flatten_with_path(arg)[0]:
            bad = ~jnp.isfinite(jnp.asarray(leaf))
            if bool(jnp.any(bad)):
                where = name + jax.tree_util.keystr(path)
                raise ValueError(f"{where} contains non-finite values at {jnp.argwhere(bad)[0]}")
    # The named stage checks (non-finite constants or leaf outputs, leaf metrics that are not
    # positive semi-definite) say which leaf is at fault; the primitive-level float checks say
    # which operation made the first NaN. A named error is raised with that operation appended
    # (a bad leaf metric makes the resolve's Cholesky the first NaN, docs/design.md §5.10).
    # Each checked function is compiled, not run op by op: the same checks, one XLA program
    # each (a hand-designed policy's debug call on a 2-core CPU: 1.9 s instead of 4.3 s).
    float_err, _ = jax.jit(checkify.checkify(fn, errors=checkify.float_checks))(*args)
    named_err, out = jax.jit(checkify.checkify(fn, errors=checkify.user_checks))(*args)
    named, first_nan = named_err.get(), float_err.get()
    if named is not None:
        raise checkify.JaxRuntimeError(
            named if first_nan is None else f"{named}\n(the first NaN: {first_nan})")
    float_err.throw()
    return out


# --------------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------------


def pullback(task_map: TaskMap, leaf_fn: LeafFn, q: jax.Array, qd: jax.Array, *ctx: Any) -> RMP:
    """Root RMP ``[M, f]`` with ``M = Σ JᵀM_kJ`` and ``f = Σ Jᵀ(f_k − M_k J̇q̇)`` (eqs 3.10, 3.31).

    ``q`` and ``qd`` are single configurations of shape ``(d,)`` (batch with ``jax.vmap``);
    ``ctx`` (goal, obstacles, parameters) is passed to both ``task_map`` and ``leaf_fn``.
    """
    q = check_configuration("q", q)
    qd = check_configuration("qd", qd, q.shape[0])
    return _pullback(task_map, leaf_fn, q, qd, ctx, False)


def resolve(root: RMP) -> jax.Array:
    """Root acceleration ``q̈ = M⁻¹ f`` with the original numerics (eq 3.10).

    ``M`` and ``f`` are divided by ``max(1, 0.01·max|M_ij|)``, ``1e-3·I`` is added to ``M``,
    and the symmetric positive-definite system is solved by Cholesky
    (:func:`mjxrmp.core.linalg.spd_solve`).
    """
    return _resolve(root)


def acceleration(
    task_map: TaskMap, leaf_fn: LeafFn, q: jax.Array, qd: jax.Array, *ctx: Any,
    debug: bool = False,
) -> jax.Array:
    """RMP² policy ``q̈ = π(q, q̇)``: :func:`resolve` ∘ :func:`pullback` (Algorithm 2, eq 3.10).

    With ``debug=True`` (concrete inputs only) the computation runs under ``checkify`` and raises
    on the first non-finite value, naming where it arose, or on a leaf metric that is not
    positive semi-definite, naming the leaf (its path in the task map's output) and member.
    """
    q = check_configuration("q", q)
    qd = check_configuration("qd", qd, q.shape[0])
    run = lambda q, qd, ctx: _resolve(_pullback(task_map, leaf_fn, q, qd, ctx, debug))  # noqa: E731
    return _run_debug(run, (q, qd, ctx)) if debug else run(q, qd, ctx)


def pullback_velocity(task_map: TaskMap, leaf_fn: LeafFn, q: jax.Array, *ctx: Any) -> RMP:
    """Root of the first-order form (eq 5.1): ``[Σ JᵀM_kJ, Σ Jᵀp_k]`` with ``p_k = M_k v_k``.

    ``leaf_fn(x_tree, *ctx)`` returns ``RMP(M (n,m,m), p (n,m))`` at every leaf.
    """
    q = check_configuration("q", q)
    return _pullback_velocity(task_map, leaf_fn, q, ctx, False)


def velocity(
    task_map: TaskMap, leaf_fn: LeafFn, q: jax.Array, *ctx: Any, debug: bool = False
) -> jax.Array:
    """First-order RMP² policy ``q̇ = argmin_v Σ ½‖J_k v − v_k‖²_{M_k}`` (eq 5.1).

    Leaves return the natural pair ``RMP(M_k, p_k = M_k v_k)``; the root is resolved with the
    same numerics as :func:`resolve`.
    """
    q = check_configuration("q", q)
    run = lambda q, ctx: _resolve(_pullback_velocity(task_map, leaf_fn, q, ctx, debug))  # noqa: E731
    return _run_debug(run, (q, ctx)) if debug else run(q, ctx)
