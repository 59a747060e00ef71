"""Learning RMP² policies for the Franka from demonstrations: the strategies of thesis chapter 5.

**Policy class** (§5.3.1). ``K`` learned leaves, each a subtask map, a latent potential and a
latent Riemannian metric ``(ψ_k, Φ̄, G_k)``:

* ``ψ_k(q) = φ_k(x_k(q)) − φ_k(0)`` with ``x_k(q) = FK_k(q) − g_k`` the k-th hand control point
  relative to its goal (§5.2.3; :func:`mjxrmp.data.franka_demos.hand_points`) — or, for
  configuration-space regression, ``x(q) = q − q_g`` — and ``φ_k`` a Euclideanizing flow
  (§4.2.2, eqs 4.4–4.5; :class:`mjxrmp.learned.flows.EuclideanizingFlow`);
* ``Φ̄(y) = ½γ‖y‖²`` (§5.3.1, "a simple pre-specified potential"; ``γ`` = ``latent_gain``);
* ``G_k(y)`` a Cholesky metric network on the latent space (§4.3.1, §5.2.2;
  :class:`mjxrmp.learned.gds.CholeskyMetric`, exactly ``I`` at initialisation).

Leaf k is the velocity-form RMP ``(M_k, v_k) = (G_k, −G_k⁻¹∇Φ̄)`` (§5.3.1), i.e. the natural pair
``(G_k, p_k = −γ y_k)``. As in §5.3.2 a hand-specified *default* leaf on each control point pulls
it in a straight line to its goal: ``(w I, p = −w γ_d x_k)`` (a convex potential
``½γ_d‖x_k‖²`` with the constant inertia ``w``, ``default_weight`` = 10 as in §5.3.2, ``γ_d`` =
``default_gain``; ``w = 0`` removes it). The configuration-space policy is the velocity-form RMP²
of eq 5.1,

    q̇ = π_θ(q) = argmin_v Σ_k ½‖J_k v − v_k‖²_{G_k} + ½‖J_{x,k} v − v_k^d‖²_{wI}
        = (Σ_k J_kᵀ G_k J_k + w J_{x,k}ᵀ J_{x,k} + εI)⁻¹ Σ_k (J_kᵀ p_k − w γ_d J_{x,k}ᵀ x_k),   (*)

``J_k = ∂ψ_k/∂q``, ``J_{x,k} = ∂x_k/∂q``, with the small diagonal offset ``ε``
(``regularization``, 0.02 as in §5.3.2) that keeps the root metric non-singular (three points on
the rigid hand constrain at most 6 of the 7 joints; one control point only 3). The default leaves
are part of the policy class during learning too (the joint strategy learns to bias against them,
§5.3.2). **Stability for every θ:** ``V(q) = Σ_k [Φ̄(ψ_k(q)) + ½wγ_d‖x_k(q)‖²]`` has
``V̇ = −fᵀ(M + εI)⁻¹f ≤ 0`` with ``f`` the right-hand side of (*) (``f = −∇V``); each ``ψ_k`` is a
diffeomorphism of the control point with ``ψ_k = 0`` only at its goal.

**Strategies** (:data:`STRATEGIES`), each a two-stage fit (docs/design.md §4.6): stage 1 trains the
flows with the latent metrics held at ``I``; stage 2 trains the metrics with the flows frozen.
Every stage is one ``lax.scan`` of Adam steps (weight decay ``1e-8`` as an L2 term, §5.3.2;
full batch, or minibatches drawn ``∝ w`` with ``batch_size``), the whole fit one jittable
function ``train(key, samples)`` that ``vmap``s over seeds and over demonstration subsets (the
per-sample weights ``samples.w`` select the demonstrations, so leave-one-out folds share one
array and differ only in ``w``). Losses are SmoothL1 (``β``) averaged over coordinates, leaves
and (weighted) samples.

* ``"cspace"`` — configuration-space regression (§5.1 eq 5.2): one leaf on ``x = q − q_g``
  (``J = ∂ψ/∂q`` square), loss ``SmoothL1(π_θ(q) − q̇_demo)`` — a *stable* flow DS in
  configuration space (docs/design.md §4.6) rather than an unconstrained regressor, so that its
  rollouts can be compared with the others'.
* ``"independent"`` — independent per-subtask learning (§5.1 eq 5.3, §5.2): each control point's
  leaf is fitted on its own, to reproduce that point's demonstrated velocity in its task space,
  ``ẋ_k = J_{φ_k}⁻¹ G_k⁻¹(−∇Φ̄(y_k))`` (the single-leaf solution of eq 5.1; eq 5.6 in the latent
  coordinates); the leaves meet each other and the default leaves only at execution, through
  (*). The fits are ``vmap``-ped over the leaves, so they are exactly independent.
* ``"joint"`` — joint learning through the velocity-form RMP² (§5.1 eq 5.4, §5.3, eq 5.8):
  ``mean_k SmoothL1(J_{FK,k}(π_θ(q) − q̇_demo))``, differentiating through the resolve (*)
  (default leaves included, ``λ_k = 1``).
  ``J_{FK,k}`` is the task-space Jacobian of the control point (so errors are control-point
  velocities in m/s; eq 5.4 writes the subtask Jacobian, which would make the weighting depend
  on the learned flow).
* ``"single_link"`` — the single-link baseline of §5.3.2: only the centre control point, learned
  independently.
* ``"two_step"`` — the two-step strategy of §5.2 (a nominal-demonstration potential per control
  point, then a Cholesky metric by eq 5.6; no flows): trained by :mod:`agents.lfd.two_step`
  (its potential fit runs on the host, so :func:`make_train` refuses it); executed here, with
  the leaf ``(G_k, −∇Φ_k)`` in place of the flow-based learned leaf.

**Execution** (:func:`policy_velocity`, :func:`rollout`): (*) evaluated by
:func:`mjxrmp.core.rmp2.pullback_velocity` (Jacobians by forward-mode autodiff through FK and the
flows), optionally with hand-specified leaves added "at execution time" (§5.2.3), the same for
every strategy (:class:`ExecutionParams`): a velocity-form joint-limit RMP (a barrier metric
growing like ``1/s²`` within ``ℓ`` of a buffered limit and a repelling velocity), a
configuration-space posture default leaf (§5.3.2), and the hand-designed collision leaves of
:mod:`mjxrmp.policies`. Those are acceleration-form leaves ``(M_h(x, ẋ), f_h = M_h a_h(x, ẋ))``;
in the velocity form each contributes its metric at the current leaf velocity ``ẋ = J q̇_prev``
(the previous command) and the desired velocity ``h·a_h(x, 0)`` — one integration step ``h`` of
its damping-free (repulsive) acceleration: ``p_h = M_h(x, ẋ)·h·a_h(x, 0)``. The damping terms of
those leaves are not needed in a first-order system (velocities do not accumulate), and their
stiffness would make an explicit step unstable. (The lifted acceleration-form joint-limit leaf
used before was too weak at a 0.05 s step: its metric ``0.1/(s/0.01 + 0.001)`` is ~0.01 at
0.1 rad from a limit, negligible against the learned and default leaves, and 73 of 126 door
rollouts of the joint strategy left the limits.) Rollouts integrate
``q ← q + h·clip(q̇, ±q̇_max)`` in one ``lax.scan`` (``ExecutionParams.substeps`` Euler steps
of ``h = dt/substeps`` per control step ``dt``).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from agents.lfd.flow_field import early_stop_update, regularised_adam
from mjxrmp import policies
from mjxrmp.core import rmp2
from mjxrmp.core.rmp import RMP
from mjxrmp.data.franka_demos import StackedDemos, hand_points
from mjxrmp.geometry import Obstacles
from mjxrmp.learned.flows import CONSTANTS, EuclideanizingFlow
from mjxrmp.learned.gds import CholeskyMetric
from mjxrmp.leaves.hand_designed import CollisionParams
from mjxrmp.robots import franka

STRATEGIES = ("cspace", "independent", "joint", "single_link", "two_step")
#: Strategies fitted leaf by leaf (eq 5.3) rather than through the resolve (eqs 5.2, 5.4).
INDEPENDENT_STRATEGIES = ("independent", "single_link")
DOF = franka.FRANKA.dof

__all__ = [
    "INDEPENDENT_STRATEGIES",
    "STRATEGIES",
    "Execution",
    "ExecutionParams",
    "Samples",
    "StrategyConfig",
    "StrategyResult",
    "execution_config",
    "fold_trainer",
    "fold_weights",
    "init_params",
    "joint_limit_distances",
    "joint_limit_leaf",
    "latent_leaves",
    "make_samples",
    "make_train",
    "policy_velocity",
    "resolve_velocity",
    "rollout",
    "strategy_loss",
    "task_coordinates",
    "training_velocity",
]


def _check_int(value: Any, name: str, minimum: int) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"StrategyConfig.{name} must be an int >= {minimum}, got {value!r}")


def _check_float(value: Any, name: str, allow_zero: bool = False) -> None:
    ok = isinstance(value, (int, float, np.floating)) and not isinstance(value, bool) \
        and math.isfinite(value) and (value >= 0 if allow_zero else value > 0)
    if not ok:
        raise ValueError(f"StrategyConfig.{name} must be a finite number "
                         f"{'>= 0' if allow_zero else '> 0'}, got {value!r}")


@dataclasses.dataclass(frozen=True)
class StrategyConfig:
    """One strategy's model and training settings (module docstring).

    Defaults are the thesis' (§5.3.2) and docs/design.md §4.6 values: flows of 10 coupling layers with
    200 random Fourier features of length-scale 0.45, Cholesky metrics ``(128, 64)``, Adam with
    learning rate ``1e-4`` and weight decay ``1e-8``, ``ε = 0.02``; iteration counts are
    configurable (``flow_iterations`` for stage 1, ``metric_iterations`` for stage 2, which may be
    0); ``batch_size`` (``None``: full batch, the thesis) draws a minibatch per step;
    ``patience`` (``None``: off, the thesis) stops a stage early and keeps its best parameters.
    :meth:`cpu` is a preset that finishes in minutes on a 2-core CPU; :meth:`reference` adds
    the LASA reference code's clip and early stop to the thesis values; :meth:`tiny` is for
    tests. ``point`` is the control point used by ``"single_link"`` (0: the centre).
    """

    strategy: str = "joint"
    num_layers: int = 10
    num_features: int = 200
    length_scale: float = 0.45
    metric_hidden: tuple[int, ...] = (128, 64)
    latent_gain: float = 1.0
    default_weight: float = 10.0
    default_gain: float = 1.0
    regularization: float = 0.02
    smooth_l1_beta: float = 1.0
    learning_rate: float = 1e-4
    metric_learning_rate: float = 1e-4
    weight_decay: float = 1e-8
    max_grad_norm: float | None = None
    batch_size: int | None = None
    flow_iterations: int = 5000
    metric_iterations: int = 5000
    patience: int | None = None
    point: int = 0

    def __post_init__(self) -> None:
        if self.strategy not in STRATEGIES:
            raise ValueError(f"StrategyConfig.strategy must be one of {STRATEGIES}, "
                             f"got {self.strategy!r}")
        _check_int(self.num_layers, "num_layers", 1)
        _check_int(self.num_features, "num_features", 1)
        _check_float(self.length_scale, "length_scale")
        if not isinstance(self.metric_hidden, tuple):
            object.__setattr__(self, "metric_hidden", tuple(self.metric_hidden))
        for h in self.metric_hidden:
            _check_int(h, "metric_hidden entries", 1)
        _check_float(self.default_weight, "default_weight", allow_zero=True)
        for name in ("latent_gain", "default_gain", "regularization", "smooth_l1_beta",
                     "learning_rate", "metric_learning_rate"):
            _check_float(getattr(self, name), name)
        _check_float(self.weight_decay, "weight_decay", allow_zero=True)
        if self.max_grad_norm is not None:
            _check_float(self.max_grad_norm, "max_grad_norm")
        if self.batch_size is not None:
            _check_int(self.batch_size, "batch_size", 1)
        _check_int(self.flow_iterations, "flow_iterations", 1)
        _check_int(self.metric_iterations, "metric_iterations", 0)
        if self.patience is not None:
            _check_int(self.patience, "patience", 1)
        _check_int(self.point, "point", 0)
        if self.point > 2:
            raise ValueError(f"StrategyConfig.point must be 0, 1 or 2 (a hand control point), "
                             f"got {self.point!r}")

    @classmethod
    def cpu(cls, strategy: str = "joint", **overrides: Any) -> StrategyConfig:
        """CPU preset: flows of 4 layers × 32 features, metrics ``(32, 32)``, minibatches of 256,
        400 + 200 iterations at learning rates ``5e-3`` / ``2e-3`` (the thesis' ``1e-4`` needs
        thousands of iterations), SmoothL1 ``β = 0.1`` (velocities are ~0.1 m/s, so ``β = 1``
        is a plain squared loss), gradient-norm clip 1, and weight decay ``1e-2`` (pulls the
        flows towards the identity, i.e. towards the straight-line default, away from the data:
        with the thesis' ``1e-8`` the joint strategy's learned potentials had spurious minima
        that trapped 24 of 60 door rollouts started at the *training* demonstrations' starts
        (exact and perturbed, all six folds); with ``1e-2`` none, same check)."""
        base: dict[str, Any] = dict(num_layers=4, num_features=32, metric_hidden=(32, 32),
                                    learning_rate=5e-3, metric_learning_rate=2e-3,
                                    smooth_l1_beta=0.1, max_grad_norm=1.0, batch_size=256,
                                    flow_iterations=400, metric_iterations=200,
                                    weight_decay=1e-2)
        base.update(overrides)
        return cls(strategy=strategy, **base)

    @classmethod
    def reference(cls, strategy: str = "joint", **overrides: Any) -> StrategyConfig:
        """The thesis sizes and rates with the training rules of the LASA reference code
        (docs/design.md §4.6), which §5.3.2 does not state: gradient-norm clip 0.1, early stop
        after 250 iterations without a lower loss (the best parameters are kept), per stage."""
        base: dict[str, Any] = dict(max_grad_norm=0.1, patience=250)
        base.update(overrides)
        return cls(strategy=strategy, **base)

    @classmethod
    def tiny(cls, strategy: str = "joint", **overrides: Any) -> StrategyConfig:
        """Seconds-scale preset for tests: 1 coupling layer of 8 features, metric ``(8,)``,
        30 + 10 iterations at learning rate ``1e-2``."""
        base: dict[str, Any] = dict(num_layers=1, num_features=8, metric_hidden=(8,),
                                    learning_rate=1e-2, metric_learning_rate=1e-2,
                                    smooth_l1_beta=0.1, flow_iterations=30, metric_iterations=10)
        base.update(overrides)
        return cls(strategy=strategy, **base)

    def replace(self, **changes: Any) -> StrategyConfig:
        return dataclasses.replace(self, **changes)

    @property
    def num_leaves(self) -> int:
        """``K``: 3 hand control points, or 1 (configuration space / single link)."""
        return 1 if self.strategy in ("cspace", "single_link") else 3

    @property
    def leaf_dim(self) -> int:
        """``m``: 7 for configuration-space regression, else 3."""
        return DOF if self.strategy == "cspace" else 3

    @property
    def flow(self) -> EuclideanizingFlow:
        return EuclideanizingFlow(dim=self.leaf_dim, num_layers=self.num_layers,
                                  num_features=self.num_features,
                                  length_scale=self.length_scale)

    @property
    def metric(self) -> CholeskyMetric:
        return CholeskyMetric(dim=self.leaf_dim, hidden_sizes=self.metric_hidden)


# ---------------------------------------------------------------------------------------------
# Data
# ---------------------------------------------------------------------------------------------


class Samples(NamedTuple):
    """Training pairs, one row per demonstration sample (a pytree; ``S`` samples):
    ``x (S, K, m)`` task coordinates relative to the goal, ``J (S, K, m, 7)`` their Jacobians
    ``∂x/∂q``, ``xd (S, K, m)`` demonstrated task velocities, ``qd (S, 7)`` demonstrated joint
    velocities, ``w (S,)`` sample weights (0: not used)."""

    x: jax.Array
    J: jax.Array
    xd: jax.Array
    qd: jax.Array
    w: jax.Array


def task_coordinates(strategy: str, point: int, q: jax.Array, goals: jax.Array,
                     q_goal: jax.Array) -> jax.Array:
    """``x(q) (K, m)``: control points minus their goals (§5.2.3, ``FK_k − g_k``) for
    ``"joint"``/``"independent"``, the ``point``-th one for ``"single_link"``, ``q − q_g``
    for ``"cspace"``. ``goals (3, 3)``, ``q_goal (7,)``, one configuration ``q (7,)``."""
    if strategy == "cspace":
        return (q - q_goal)[None]
    x = hand_points(q) - goals
    return x[point:point + 1] if strategy == "single_link" else x


def make_samples(config: StrategyConfig, demos: StackedDemos) -> Samples:
    """:class:`Samples` of every (padded) sample of ``demos`` with ``w = mask`` (fold weights
    come from :func:`fold_weights`). Jacobians by forward-mode autodiff of the kinematics."""
    s, k = config.strategy, config.point
    N, T = demos.mask.shape

    def one(q, qd, pv, g, qg):
        fn = lambda q_: task_coordinates(s, k, q_, g, qg)  # noqa: E731
        x = fn(q)
        J = jax.jacfwd(fn)(q)
        xd = qd[None] if s == "cspace" else pv[k:k + 1] if s == "single_link" else pv
        return x, J, xd

    rep = lambda a: jnp.repeat(a[:, None], T, axis=1).reshape((N * T, *a.shape[1:]))  # noqa: E731
    flat = lambda a: a.reshape((N * T, *a.shape[2:]))  # noqa: E731
    x, J, xd = jax.jit(jax.vmap(one))(flat(demos.q), flat(demos.qd),
                                      flat(demos.point_velocities), rep(demos.goals),
                                      rep(demos.q_goal))
    return Samples(x=x, J=J, xd=xd, qd=flat(demos.qd), w=flat(demos.mask))


def fold_weights(mask: jax.Array, train: jax.Array) -> jax.Array:
    """Sample weights ``(N·T,)`` using the demonstrations with ``train (N,)`` true:
    ``mask (N, T) · train[:, None]``, flattened like :func:`make_samples`."""
    mask = jnp.asarray(mask)
    train = jnp.asarray(train, mask.dtype)
    if train.shape != mask.shape[:1]:
        raise ValueError(f"train must have shape ({mask.shape[0]},), got {train.shape}")
    return (mask * train[:, None]).reshape(-1)


# ---------------------------------------------------------------------------------------------
# The policy
# ---------------------------------------------------------------------------------------------


class StrategyResult(NamedTuple):
    """A fitted policy: ``params = {"flow", "metric"}`` and ``constants`` (the flows' fixed
    random features), every leaf stacked over the ``K`` leaves; the loss of every iteration of
    both stages, ``flow_losses (flow_iterations,)`` and ``metric_losses (metric_iterations,)``
    (for ``"independent"`` the mean over leaves)."""

    params: Any
    constants: Any
    flow_losses: jax.Array
    metric_losses: jax.Array


def init_params(config: StrategyConfig, key: jax.Array) -> tuple[Any, Any]:
    """Initial ``(params, constants)`` of the ``K`` leaves (stacked): flows at the identity,
    metrics at ``I`` (§4.2.2, §4.3.1)."""
    m = config.leaf_dim

    def one(k):
        k_flow, k_metric = jax.random.split(k)
        fv = config.flow.init(k_flow, jnp.zeros((m,), jnp.float32))
        mp = config.metric.init(k_metric, jnp.zeros((m,), jnp.float32))["params"]
        return {"flow": fv["params"], "metric": mp}, fv[CONSTANTS]

    return jax.vmap(one)(jax.random.split(key, config.num_leaves))


def latent_leaves(config: StrategyConfig, params: Any, constants: Any, x: jax.Array
                  ) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Per leaf ``y_k = φ_k(x_k) − φ_k(0)``, ``J_{φ_k}(x_k)`` and ``G_k(y_k)`` for one sample
    ``x (K, m)``: ``(y (K, m), Jφ (K, m, m), G (K, m, m))`` (§4.2, §5.3.1)."""
    flow, metric = config.flow, config.metric

    def one(fp, fc, mp, xk):
        fv = {"params": fp, CONSTANTS: fc}

        def phi(z):
            y = flow.apply(fv, z)
            return y, y

        Jphi, y = jax.jacfwd(phi, has_aux=True)(xk)
        y = y - flow.apply(fv, jnp.zeros_like(xk))
        return y, Jphi, metric.apply({"params": mp}, y)

    return jax.vmap(one)(params["flow"], constants, params["metric"], x)


def resolve_velocity(M: jax.Array, f: jax.Array, regularization: float) -> jax.Array:
    """``q̇ = (M + εI)⁻¹ f``: the velocity-form root resolve of eq 5.1 with the diagonal offset
    ``ε`` of §5.3.2 (``M = Σ J_kᵀ G_k J_k``, ``f = Σ J_kᵀ p_k``)."""
    eye = jnp.eye(M.shape[-1], dtype=M.dtype)
    with jax.default_matmul_precision("highest"):
        return jnp.linalg.solve(M + regularization * eye, f)


def training_velocity(config: StrategyConfig, params: Any, constants: Any, x: jax.Array,
                      J: jax.Array) -> jax.Array:
    """(*) of the module docstring at one sample from its task coordinates ``x (K, m)`` and their
    Jacobians ``J (K, m, 7)`` (so ``J_k = J_{φ_k} J``): the policy the losses differentiate."""
    y, Jphi, G = latent_leaves(config, params, constants, x)
    A = jnp.einsum("kab,kbq->kaq", Jphi, J)
    p = -config.latent_gain * y
    M = jnp.einsum("kaq,kab,kbr->qr", A, G, A)
    f = jnp.einsum("kaq,ka->q", A, p)
    w = config.default_weight
    M = M + w * jnp.einsum("kaq,kar->qr", J, J)
    f = f - w * config.default_gain * jnp.einsum("kaq,ka->q", J, x)
    return resolve_velocity(M, f, config.regularization)


def _leaf_task_velocity(config: StrategyConfig, params: Any, constants: Any, x: jax.Array
                        ) -> jax.Array:
    """``ẋ_k = J_{φ_k}⁻¹ G_k⁻¹ (−γ y_k)`` per leaf, ``(K, m)``: each leaf alone (eq 5.3)."""
    y, Jphi, G = latent_leaves(config, params, constants, x)
    v_latent = jnp.linalg.solve(G, -config.latent_gain * y[..., None])
    return jnp.linalg.solve(Jphi, v_latent)[..., 0]


def _smooth_l1(err: jax.Array, beta: float) -> jax.Array:
    return optax.losses.huber_loss(err, delta=beta) / beta


def strategy_loss(config: StrategyConfig, params: Any, constants: Any, samples: Samples
                  ) -> jax.Array:
    """The training loss of ``config.strategy`` (module docstring) on weighted ``samples``.

    ``"cspace"``: ``SmoothL1(π(q) − q̇_d)`` (eq 5.2); ``"joint"``: ``mean_k SmoothL1(J_{FK,k}(π(q)
    − q̇_d))`` (eq 5.4); ``"independent"``/``"single_link"``: ``mean_k SmoothL1(ẋ_k − ẋ_{d,k})``
    with each leaf alone (eq 5.3). Means over coordinates and leaves, weighted mean over samples.
    """
    beta = config.smooth_l1_beta
    if config.strategy in INDEPENDENT_STRATEGIES:
        pred = jax.vmap(lambda x: _leaf_task_velocity(config, params, constants, x))(samples.x)
        per = jnp.mean(_smooth_l1(pred - samples.xd, beta), axis=(1, 2))
    else:
        qd = jax.vmap(lambda x, J: training_velocity(config, params, constants, x, J))(
            samples.x, samples.J)
        err = jnp.einsum("skaq,sq->ska", samples.J, qd - samples.qd)
        per = jnp.mean(_smooth_l1(err, beta), axis=(1, 2))
    w = samples.w
    return jnp.sum(w * per) / jnp.maximum(jnp.sum(w), 1.0)


# ---------------------------------------------------------------------------------------------
# Training
# ---------------------------------------------------------------------------------------------


def _optimizer(config: StrategyConfig, learning_rate: float) -> optax.GradientTransformation:
    return regularised_adam(learning_rate, config.weight_decay, config.max_grad_norm)


def _fit(loss: Callable[[Any, jax.Array], jax.Array], params: Any,
         tx: optax.GradientTransformation, iterations: int, key: jax.Array,
         patience: int | None = None) -> tuple[Any, jax.Array]:
    """``iterations`` steps of ``tx`` on ``loss(params, key)`` in one ``lax.scan`` (a fresh key
    per step for minibatches); a step whose loss is not finite leaves the parameters unchanged.
    With ``patience`` (the LASA reference code's early stop, docs/design.md §4.6) the parameters
    freeze once the loss has not improved on its lowest value for ``patience`` steps, and the
    parameters of the lowest loss are returned. Returns the parameters and the loss before
    every step."""
    if iterations == 0:
        return params, jnp.zeros((0,), jnp.float32)

    def pick(flag, new, old):
        return jax.tree.map(lambda a, b: jnp.where(flag, a, b), new, old)

    def step(carry, k):
        p, opt, best = carry  # best: early-stop record (``()`` without patience)
        value, grads = jax.value_and_grad(loss)(p, k)
        updates, new_opt = tx.update(grads, opt, p)
        move = jnp.isfinite(value)
        if patience is not None:
            _, *best, move, stopped = early_stop_update(value, p, *best, patience)
            best = (*best, stopped)
        return (pick(move, optax.apply_updates(p, updates), p), pick(move, new_opt, opt),
                best), value

    best = () if patience is None else (params, jnp.asarray(jnp.inf, jnp.float32),
                                        jnp.zeros((), jnp.int32), jnp.zeros((), bool))
    (last, _, best), losses = jax.lax.scan(step, (params, tx.init(params), best),
                                           jax.random.split(key, iterations))
    return (last if patience is None else best[0]), losses


def _minibatch(samples: Samples, key: jax.Array, batch_size: int | None) -> Samples:
    """``batch_size`` samples drawn with probability ``∝ w`` (with replacement, then weighted
    equally), or all samples when ``batch_size`` is ``None``."""
    if batch_size is None:
        return samples
    w = samples.w
    idx = jax.random.choice(key, w.shape[0], (batch_size,), p=w / jnp.sum(w))
    picked = jax.tree.map(lambda a: a[idx], samples)
    return picked._replace(w=jnp.ones((batch_size,), w.dtype))


def _two_stage(config: StrategyConfig, params: Any, constants: Any, samples: Samples,
               key: jax.Array) -> tuple[Any, jax.Array, jax.Array]:
    """Stage 1: flows with the metrics at their initial value ``I``; stage 2: metrics with the
    flows frozen (docs/design.md §4.6)."""
    def loss(p, k):
        return strategy_loss(config, p, constants, _minibatch(samples, k, config.batch_size))

    k1, k2 = jax.random.split(key)
    flow, flow_losses = _fit(lambda fp, k: loss({**params, "flow": fp}, k), params["flow"],
                             _optimizer(config, config.learning_rate), config.flow_iterations, k1,
                             config.patience)
    metric, metric_losses = _fit(lambda mp, k: loss({"flow": flow, "metric": mp}, k),
                                 params["metric"],
                                 _optimizer(config, config.metric_learning_rate),
                                 config.metric_iterations, k2, config.patience)
    return {"flow": flow, "metric": metric}, flow_losses, metric_losses


def make_train(config: StrategyConfig) -> Callable[[jax.Array, Samples], StrategyResult]:
    """``train(key, samples) -> StrategyResult`` for ``config`` (module docstring): initialise
    the ``K`` leaves from ``key`` and run both stages. Pure and jittable; ``jax.vmap`` it over
    keys (seeds) and/or ``samples.w`` (demonstration subsets)."""
    if not isinstance(config, StrategyConfig):
        raise TypeError(f"config must be a StrategyConfig, got {type(config)}")
    if config.strategy == "two_step":
        raise ValueError("strategy 'two_step' needs the nominal potentials of its training "
                         "demonstrations: train it with agents.lfd.two_step.train_folds")

    def check(samples: Samples) -> None:
        K, m = config.num_leaves, config.leaf_dim
        S = samples.w.shape[0]
        want = Samples((S, K, m), (S, K, m, DOF), (S, K, m), (S, DOF), (S,))
        for name, shape, got in zip(Samples._fields, want, samples, strict=True):
            if got.shape != shape:
                raise ValueError(f"samples.{name} must have shape {shape} for strategy "
                                 f"{config.strategy!r}, got {got.shape}")

    def train(key: jax.Array, samples: Samples) -> StrategyResult:
        check(samples)
        k_init, k_fit = jax.random.split(key)
        params, constants = init_params(config, k_init)
        if config.strategy not in INDEPENDENT_STRATEGIES:
            out, fl, ml = _two_stage(config, params, constants, samples, k_fit)
            return StrategyResult(out, constants, fl, ml)
        # Independent leaves: the same two-stage fit, vmapped over leaves (eq 5.3).
        one = dataclasses.replace(config, strategy="single_link", point=0)

        def leaf(p, c, x, J, xd, k):
            p1 = jax.tree.map(lambda a: a[None], p)
            c1 = jax.tree.map(lambda a: a[None], c)
            s1 = samples._replace(x=x[:, None], J=J[:, None], xd=xd[:, None])
            out, fl, ml = _two_stage(one, p1, c1, s1, k)
            return jax.tree.map(lambda a: a[0], out), fl, ml

        out, fl, ml = jax.vmap(leaf, in_axes=(0, 0, 1, 1, 1, 0))(
            params, constants, samples.x, samples.J, samples.xd,
            jax.random.split(k_fit, config.num_leaves))
        return StrategyResult(out, constants, jnp.mean(fl, axis=0), jnp.mean(ml, axis=0))

    return train


@functools.lru_cache(maxsize=16)
def fold_trainer(config: StrategyConfig) -> Callable[[jax.Array, Samples, jax.Array],
                                                     StrategyResult]:
    """``train(keys (F, 2), samples, weights (F, S)) -> StrategyResult`` (leaves with a leading
    ``F``): :func:`make_train` jitted and ``vmap``-ped over keys and sample weights (seeds and/or
    demonstration subsets, e.g. leave-one-out folds), cached per configuration so that every
    caller with the same configuration and array shapes shares one compiled program."""

    def train(keys: jax.Array, samples: Samples, weights: jax.Array) -> StrategyResult:
        return jax.vmap(make_train(config), in_axes=(0, Samples(None, None, None, None, 0)))(
            keys, samples._replace(w=weights))

    return jax.jit(train)


# ---------------------------------------------------------------------------------------------
# Execution
# ---------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class ExecutionParams:
    """The hand-specified leaves added at execution time (§5.2.3: "additional hand-specified
    joint limit RMPs, and obstacle avoidance RMPs"; §5.3.2: default subtask policies) in the
    velocity form, and the integrator. Applied identically to every strategy.

    * **Joint limits** (velocity form, on the buffered distances ``s = [q_u − q, q − q_l]`` of
      :data:`mjxrmp.policies.FRANKA_JOINT_LIMIT_BUFFERS`, clipped ≥ 0): the barrier metric
      ``m(s) = μ·(relu(1 − s/ℓ) / (s/ℓ + ε_j))²`` (zero farther than ``ℓ`` from a limit, growing
      like ``1/s²`` near it) and the repelling velocity ``ṡ_d = v_r·relu(1 − s/ℓ)``. Each is a
      function of one joint angle, so ``m(s)ṡ_d`` is the gradient of a 1-D potential and the
      Lyapunov argument of the module docstring still holds; near a limit the resolve's ``ṡ``
      is pulled towards ``ṡ_d ≥ 0`` with a weight that dominates every learned leaf.
    * **Posture** (a configuration-space default leaf, §5.3.2): ``(w_c I, −w_c γ_c (q − q_p))``
      towards a posture ``q_p`` (the scripts use the mean final configuration of the *training*
      demonstrations), which fixes the hand's redundant joint and damps drift away from the data
      (``w_c = 0`` removes it).
    * ``substeps``: each control step ``dt`` is integrated by that many explicit Euler steps of
      ``dt/substeps`` (the policy re-evaluated at each).
    """

    joint_limit_length: float = 0.25
    joint_limit_scale: float = 1.0
    joint_limit_eps: float = 0.01
    joint_limit_speed: float = 0.5
    posture_weight: float = 0.1
    posture_gain: float = 0.5
    substeps: int = 1

    def __post_init__(self) -> None:
        for name in ("joint_limit_length", "joint_limit_scale", "joint_limit_eps",
                     "joint_limit_speed", "posture_gain"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                    and v > 0):
                raise ValueError(f"ExecutionParams.{name} must be a finite number > 0, got {v!r}")
        w = self.posture_weight
        if not (isinstance(w, (int, float)) and not isinstance(w, bool) and math.isfinite(w)
                and w >= 0):
            raise ValueError(f"ExecutionParams.posture_weight must be a finite number >= 0, "
                             f"got {w!r}")
        if isinstance(self.substeps, bool) or not isinstance(self.substeps, int) \
                or self.substeps < 1:
            raise ValueError(f"ExecutionParams.substeps must be an int >= 1, "
                             f"got {self.substeps!r}")


class Execution(NamedTuple):
    """Execution-time context of :func:`policy_velocity`: the ``obstacles``, the previous command
    ``qd_prev (7,)`` and step ``h`` (for the lifted collision leaves), the posture ``q_posture
    (7,)`` and its weight ``posture_weight`` (a scalar, may be traced: it overrides
    ``params.posture_weight``), the leaf parameters ``params`` and the collision leaves'
    ``hand_config``."""

    obstacles: Obstacles
    qd_prev: jax.Array
    h: float
    q_posture: jax.Array
    posture_weight: jax.Array | float
    params: ExecutionParams
    hand_config: policies.PolicyConfig


def execution_config(obstacle_shape: str = "cylinder") -> policies.PolicyConfig:
    """The hand-designed acceleration-form leaves lifted at execution time (§5.2.3): the Franka
    collision RMP with its default parameters (docs/design.md §4.1). Joint limits are the
    velocity-form leaf of :class:`ExecutionParams` instead."""
    return policies.PolicyConfig(robot="franka", collision=CollisionParams(),
                                 obstacle_shape=obstacle_shape)


def joint_limit_leaf(s: jax.Array, p: ExecutionParams) -> RMP:
    """The velocity-form joint-limit RMP of :class:`ExecutionParams` on distances ``s (n, 1)``:
    ``(m(s), m(s)·ṡ_d(s))`` as a family of 1-D natural-form pairs."""
    s = jnp.maximum(s, 0.0)
    act = jax.nn.relu(1.0 - s / p.joint_limit_length)
    m = p.joint_limit_scale * (act / (s / p.joint_limit_length + p.joint_limit_eps)) ** 2
    return RMP(m[..., None], m * p.joint_limit_speed * act)


def joint_limit_distances(q: jax.Array) -> jax.Array:
    """``s = [q_u − b − q, q − q_l − b] (14, 1)``: distances to the buffered Franka limits."""
    buf = jnp.asarray(policies.FRANKA_JOINT_LIMIT_BUFFERS, q.dtype)
    upper = jnp.asarray(franka.Q_UPPER, q.dtype) - buf
    lower = jnp.asarray(franka.Q_LOWER, q.dtype) + buf
    return jnp.concatenate([upper - q, q - lower])[:, None]


def _lifted(rmp_moving: RMP, rmp_still: RMP, h: float) -> RMP:
    """Velocity-form pair ``(M(x, ẋ), M(x, ẋ)·h·a(x, 0))`` of a family of 1-D acceleration leaves
    (module docstring); ``a(x, 0) = f/M`` of the leaf at rest (``0`` where that metric
    vanishes)."""
    M, _ = rmp_moving
    M0, f0 = rmp_still
    if M.shape[-1] != 1:
        raise ValueError(f"hand-designed execution leaves must be 1-D families (n, 1), got "
                         f"M of shape {M.shape}")
    m0 = M0[..., 0]
    a0 = jnp.where(m0 > 0, f0 / jnp.where(m0 > 0, m0, 1.0), 0.0)
    return RMP(M, h * M[..., 0] * a0)


def policy_velocity(config: StrategyConfig, result: StrategyResult, q: jax.Array,
                    goals: jax.Array, q_goal: jax.Array, execution: Execution | None = None
                    ) -> jax.Array:
    """The learned policy (*) at one configuration ``q (7,)`` through
    :func:`mjxrmp.core.rmp2.pullback_velocity`; ``goals (3, 3)`` control-point goals, ``q_goal (7,)``.

    ``execution`` (:class:`Execution`) adds the execution-time leaves: the velocity-form
    joint-limit and posture leaves of :class:`ExecutionParams` and the hand-designed collision
    leaves of ``execution.hand_config`` in their velocity-form lift (module docstring) at the
    previous command. Without it this equals :func:`training_velocity` on the same sample.
    """
    s, k = config.strategy, config.point

    if s == "two_step":
        from agents.lfd import (
            two_step as lfd_two_step,  # builds on this module: imported where it is used
        )

        def learned_map(q_):
            return task_coordinates(s, k, q_, goals, q_goal)

        def learned_leaf(y):
            return lfd_two_step.leaf_rmps(config, result, y)
    else:
        def learned_map(q_):
            x = task_coordinates(s, k, q_, goals, q_goal)
            return latent_leaves(config, result.params, result.constants, x)[0]

        def learned_leaf(y):
            G = jax.vmap(lambda mp, yk: config.metric.apply({"params": mp}, yk))(
                result.params["metric"], y)
            return RMP(G, -config.latent_gain * y)

    def default_leaf(x, w, gain):
        eye = jnp.broadcast_to(jnp.eye(x.shape[-1], dtype=x.dtype), (*x.shape, x.shape[-1]))
        return RMP(w * eye, -w * gain * x)

    def base_map(q_):
        return {"learned": learned_map(q_),
                "default": task_coordinates(s, k, q_, goals, q_goal)}

    def base_leaves(x):
        return {"learned": learned_leaf(x["learned"]),
                "default": default_leaf(x["default"], config.default_weight,
                                        config.default_gain)}

    if execution is None:
        root = rmp2.pullback_velocity(base_map, base_leaves, q)
        return resolve_velocity(root.M, root.f, config.regularization)

    ex = execution
    cfg, p = ex.hand_config, ex.params
    dummy_goal = jnp.zeros((3,), q.dtype)
    hand_map = lambda q_: policies.task_map(q_, dummy_goal, ex.obstacles, cfg)  # noqa: E731
    _, xd_hand = jax.jvp(hand_map, (q,), (ex.qd_prev,))

    def full_map(q_):
        return {**base_map(q_), "hand": hand_map(q_), "joint_limit": joint_limit_distances(q_),
                "posture": (q_ - ex.q_posture)[None]}

    def leaf_fn(x):
        moving = policies.leaf_rmps(x["hand"], xd_hand, dummy_goal, ex.obstacles, cfg)
        still = policies.leaf_rmps(x["hand"], jax.tree.map(jnp.zeros_like, xd_hand),
                                   dummy_goal, ex.obstacles, cfg)
        return {**base_leaves(x),
                "hand": {n: _lifted(moving[n], still[n], ex.h) for n in moving},
                "joint_limit": joint_limit_leaf(x["joint_limit"], p),
                "posture": default_leaf(x["posture"], ex.posture_weight, p.posture_gain)}

    root = rmp2.pullback_velocity(full_map, leaf_fn, q)
    return resolve_velocity(root.M, root.f, config.regularization)


def rollout(config: StrategyConfig, result: StrategyResult, q0: jax.Array, goals: jax.Array,
            q_goal: jax.Array, num_steps: int, dt: float,
            obstacles: Obstacles | None = None,
            hand_config: policies.PolicyConfig | None = None,
            params: ExecutionParams | None = None,
            q_posture: jax.Array | None = None,
            posture_weight: jax.Array | float | None = None) -> tuple[jax.Array, jax.Array]:
    """Integrate the policy from ``q0 (7,)`` for ``num_steps`` control steps of ``dt``, each by
    ``params.substeps`` Euler steps ``q ← q + (dt/substeps)·clip(q̇, ±q̇_max)``, in one
    ``lax.scan``. With ``obstacles`` the execution-time leaves are added (:class:`Execution`:
    ``params`` default :class:`ExecutionParams`, ``hand_config`` default
    :func:`execution_config`, ``q_posture`` default ``q_goal``, ``posture_weight`` (may be
    traced, e.g. ``vmap``-ped) default ``params.posture_weight``); without, the learned policy
    alone. Returns ``(qs (num_steps + 1, 7), qds (num_steps, 7))``, ``qds`` the mean command
    over each control step."""
    if isinstance(num_steps, bool) or not isinstance(num_steps, (int, np.integer)) \
            or num_steps < 1:
        raise ValueError(f"num_steps must be a static int >= 1, got {num_steps!r}")
    if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a finite number > 0, got {dt!r}")
    q0 = rmp2.check_configuration("q0", q0, DOF)
    qd_max = jnp.asarray(franka.QD_MAX, q0.dtype)
    cfg = execution_config() if hand_config is None else hand_config
    p = ExecutionParams() if params is None else params
    h = dt / p.substeps
    q_p = q_goal if q_posture is None else q_posture
    w_p = p.posture_weight if posture_weight is None else posture_weight

    def sub(carry, _):
        q, qd_prev = carry
        ex = None if obstacles is None else Execution(obstacles, qd_prev, h, q_p, w_p, p, cfg)
        qd = jnp.clip(policy_velocity(config, result, q, goals, q_goal, ex), -qd_max, qd_max)
        return (q + h * qd, qd), qd

    def step(carry, _):
        carry, qds = jax.lax.scan(sub, carry, None, length=p.substeps)
        return carry, (carry[0], jnp.mean(qds, axis=0))

    _, (qs, qds) = jax.lax.scan(step, (q0, jnp.zeros_like(q0)), None, length=int(num_steps))
    return jnp.concatenate([q0[None], qs], axis=0), qds
