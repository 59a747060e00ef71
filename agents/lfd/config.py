"""Settings of learning from demonstrations (docs/design.md §4.6, §6): the LASA flow field, the
chapter-5 strategies, their execution-time leaves and the two-step strategy's potential fit.

Every class is a frozen dataclass validated on construction with the validators of
:mod:`mjxrmp.config`; an invalid field raises ``ValueError`` naming ``ConfigName.field``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import jax

from mjxrmp.config import check_bool, check_choice, check_float, check_int
from mjxrmp.learned.flows import ACTIVATIONS, EuclideanizingFlow
from mjxrmp.learned.gds import CholeskyMetric
from mjxrmp.robots import franka

__all__ = [
    "INDEPENDENT_STRATEGIES",
    "INTEGRATORS",
    "LATENT_POTENTIALS",
    "LOSSES",
    "SPEED_ACTIVATIONS",
    "STRATEGIES",
    "ExecutionParams",
    "LfdConfig",
    "NominalSettings",
    "StrategyConfig",
]

LATENT_POTENTIALS = ("norm", "quadratic", "blend")
LOSSES = ("smooth_l1", "mse")
INTEGRATORS = ("latent", "euler", "rk4")
SPEED_ACTIVATIONS: dict[str, Callable[[jax.Array], jax.Array]] = {
    **ACTIVATIONS, "leaky_relu": jax.nn.leaky_relu}
STRATEGIES = ("cspace", "independent", "joint", "single_link", "two_step")
#: Strategies fitted leaf by leaf (eq 5.3) rather than through the resolve (eqs 5.2, 5.4).
INDEPENDENT_STRATEGIES = ("independent", "single_link")
DOF = franka.FRANKA.dof


def _optional_int(value: Any, name: str, minimum: int = 1) -> None:
    if value is not None:
        check_int(value, name, minimum)


def _optional_float(value: Any, name: str) -> None:
    if value is not None:
        check_float(value, name)


def _hidden_sizes(obj: Any, field: str) -> None:
    """Store ``obj.field`` as a tuple of positive ints (lists are accepted)."""
    sizes = getattr(obj, field)
    if not isinstance(sizes, tuple):
        object.__setattr__(obj, field, tuple(sizes))
    for h in getattr(obj, field):
        check_int(h, f"{type(obj).__name__}.{field} entries")


@dataclasses.dataclass(frozen=True)
class LfdConfig:
    """Flow-field model and training settings; defaults are the thesis' and docs/design.md §4.6
    values (:mod:`agents.lfd.flow_field`, :mod:`agents.lfd.flow_training`).

    Flow (§4.2.2): ``num_layers`` coupling layers of ``num_features`` random Fourier features
    with ``length_scale`` (``normalize_features``: eq 4.5's ``√(2/N)`` factor, off as in the
    original implementation, for which the learning rate was tuned). Field: ``latent_potential``
    (``"norm"``, ``"quadratic"`` or ``"blend"``, their sum with the quadratic scaled by
    ``1/potential_length``), ``potential_eps`` (smoothing radius of the norm potential),
    ``scale_velocity`` with ``speed_hidden``/``speed_activation`` and the floor ``speed_min`` of
    the learned speed (``0``: the original). Arrival-time loss (:mod:`agents.lfd.flow_training`):
    ``time_weight`` (default ``0``: velocities only, as the committed LASA run; ``0.3`` with
    ``latent_potential="blend"`` is the candidate for on-time arrival, not yet run at full
    scale; not in the thesis), ``time_nodes``
    quadrature nodes of :meth:`agents.lfd.flow_field.FlowField.time_to_go`, ``time_anchors``
    samples per demonstration. Training: ``loss`` (``"smooth_l1"`` with ``smooth_l1_beta``, or
    ``"mse"``), Adam ``learning_rate``, ``weight_decay`` (L2 on the
    gradient), ``max_grad_norm`` (``None``: no clipping), ``iterations``, ``batch_size``
    (``None``: full batch; else a random subset without replacement each step), ``patience``
    (early stop; ``None``: never). ``integrator`` is the ``method`` of
    :func:`agents.lfd.flow_field.rollout` the LASA evaluation uses (default ``"latent"``: in the
    latent coordinates, convergent for every start and step; ``"euler"`` is explicit Euler in
    ``x``, consistent with the forward-difference velocity targets). ``fast_cos`` evaluates the
    random features with :func:`agents.lfd.fast_trig.fast_cos` (docs/design.md §5.6).
    """

    num_layers: int = 10
    num_features: int = 200
    length_scale: float = 0.45
    normalize_features: bool = False
    latent_potential: str = "norm"
    potential_eps: float = 1e-2
    potential_length: float = 1.0
    scale_velocity: bool = True
    speed_hidden: tuple[int, ...] = (100, 100)
    speed_activation: str = "leaky_relu"
    speed_min: float = 0.1
    time_weight: float = 0.0
    time_nodes: int = 16
    time_anchors: int = 8
    loss: str = "smooth_l1"
    smooth_l1_beta: float = 1.0
    learning_rate: float = 1e-4
    weight_decay: float = 1e-10
    max_grad_norm: float | None = 0.1
    iterations: int = 5000
    batch_size: int | None = None
    patience: int | None = 250
    integrator: str = "latent"
    fast_cos: bool = True

    def __post_init__(self) -> None:
        n = "LfdConfig."
        for name in ("num_layers", "num_features", "iterations", "time_nodes",
                     "time_anchors"):
            check_int(getattr(self, name), n + name)
        check_float(self.time_weight, n + "time_weight", allow_zero=True)
        if self.time_weight > 0.0 and not self.scale_velocity:
            raise ValueError(f"{n}time_weight > 0 trains the learned speed and needs "
                             f"{n}scale_velocity=True")
        for name in ("length_scale", "potential_eps", "potential_length", "smooth_l1_beta",
                     "learning_rate"):
            check_float(getattr(self, name), n + name)
        for name in ("normalize_features", "scale_velocity", "fast_cos"):
            check_bool(getattr(self, name), n + name)
        check_choice(self.latent_potential, n + "latent_potential", LATENT_POTENTIALS)
        check_float(self.speed_min, n + "speed_min", allow_zero=True)
        if self.speed_min >= 1.0:
            raise ValueError(f"{n}speed_min must lie in [0, 1), got {self.speed_min!r}")
        _hidden_sizes(self, "speed_hidden")
        check_choice(self.speed_activation, n + "speed_activation", sorted(SPEED_ACTIVATIONS))
        check_choice(self.loss, n + "loss", LOSSES)
        check_float(self.weight_decay, n + "weight_decay", allow_zero=True)
        _optional_float(self.max_grad_norm, n + "max_grad_norm")
        _optional_int(self.batch_size, n + "batch_size")
        _optional_int(self.patience, n + "patience")
        check_choice(self.integrator, n + "integrator", INTEGRATORS)

    @classmethod
    def tiny(cls, **overrides: Any) -> LfdConfig:
        """A seconds-scale preset for tests: 2 coupling layers of 16 features, speed MLP
        ``(16, 16)``, 60 full-batch iterations at learning rate ``1e-2`` (so that the field moves
        visibly away from the identity in few steps), no early stop."""
        base: dict[str, Any] = dict(num_layers=2, num_features=16, speed_hidden=(16, 16),
                                    learning_rate=1e-2, iterations=60, patience=None)
        base.update(overrides)
        return cls(**base)

    def replace(self, **changes: Any) -> LfdConfig:
        """A copy with ``changes`` applied (validated again)."""
        return dataclasses.replace(self, **changes)


@dataclasses.dataclass(frozen=True)
class StrategyConfig:
    """One chapter-5 strategy's model and training settings (:mod:`agents.lfd.strategies`).

    Defaults are the thesis' (§5.3.2) and docs/design.md §4.6 values: flows of 10 coupling
    layers with 200 random Fourier features of length-scale 0.45, Cholesky metrics ``(128, 64)``,
    Adam with learning rate ``1e-4`` and weight decay ``1e-8``, ``ε = 0.02``; iteration counts
    are configurable (``flow_iterations`` for stage 1, ``metric_iterations`` for stage 2, which
    may be 0); ``batch_size`` (``None``: full batch, the thesis) draws a minibatch per step;
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
        n = "StrategyConfig."
        check_choice(self.strategy, n + "strategy", STRATEGIES)
        for name in ("num_layers", "num_features", "flow_iterations"):
            check_int(getattr(self, name), n + name)
        check_int(self.metric_iterations, n + "metric_iterations", 0)
        _hidden_sizes(self, "metric_hidden")
        for name in ("length_scale", "latent_gain", "default_gain", "regularization",
                     "smooth_l1_beta", "learning_rate", "metric_learning_rate"):
            check_float(getattr(self, name), n + name)
        check_float(self.default_weight, n + "default_weight", allow_zero=True)
        check_float(self.weight_decay, n + "weight_decay", allow_zero=True)
        _optional_float(self.max_grad_norm, n + "max_grad_norm")
        _optional_int(self.batch_size, n + "batch_size")
        _optional_int(self.patience, n + "patience")
        check_int(self.point, n + "point", 0)
        check_choice(self.point, n + "point (a hand control point)", (0, 1, 2))

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

    @classmethod
    def preset(cls, name: str, strategy: str, **overrides: Any) -> StrategyConfig:
        """The preset ``name`` (``"thesis"``: the defaults, ``"cpu"``, ``"reference"`` or
        ``"tiny"``) for ``strategy`` with ``overrides``."""
        check_choice(name, "StrategyConfig preset", ("thesis", "cpu", "reference", "tiny"))
        if name == "thesis":
            return cls(strategy=strategy, **overrides)
        return getattr(cls, name)(strategy, **overrides)

    def replace(self, **changes: Any) -> StrategyConfig:
        """A copy with ``changes`` applied (validated again)."""
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
        """The leaves' Euclideanizing flow (§4.2.2)."""
        return EuclideanizingFlow(dim=self.leaf_dim, num_layers=self.num_layers,
                                  num_features=self.num_features,
                                  length_scale=self.length_scale)

    @property
    def metric(self) -> CholeskyMetric:
        """The leaves' latent Cholesky metric (§4.3.1, §5.2.2)."""
        return CholeskyMetric(dim=self.leaf_dim, hidden_sizes=self.metric_hidden)


@dataclasses.dataclass(frozen=True)
class ExecutionParams:
    """The hand-specified leaves added at execution time (§5.2.3: "additional hand-specified
    joint limit RMPs, and obstacle avoidance RMPs"; §5.3.2: default subtask policies) in the
    velocity form, and the integrator (:mod:`agents.lfd.execution`). Applied identically to
    every strategy.

    * **Joint limits** (velocity form, on the buffered distances ``s = [q_u − q, q − q_l]`` of
      :data:`mjxrmp.policies.FRANKA_JOINT_LIMIT_BUFFERS`, clipped ≥ 0): the barrier metric
      ``m(s) = μ·(relu(1 − s/ℓ) / (s/ℓ + ε_j))²`` (zero farther than ``ℓ`` from a limit, growing
      like ``1/s²`` near it) and the repelling velocity ``ṡ_d = v_r·relu(1 − s/ℓ)``. Each is a
      function of one joint angle, so ``m(s)ṡ_d`` is the gradient of a 1-D potential and the
      Lyapunov argument of :mod:`agents.lfd.policy` still holds; near a limit the resolve's
      ``ṡ`` is pulled towards ``ṡ_d ≥ 0`` with a weight that dominates every learned leaf.
    * **Posture** (a configuration-space default leaf, §5.3.2): ``(w_c I, −w_c γ_c (q − q_p))``
      towards a posture ``q_p`` (the Franka evaluation uses the mean final configuration of the
      *training* demonstrations), which fixes the hand's redundant joint and damps drift away
      from the data (``w_c = 0`` removes it).
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
            check_float(getattr(self, name), f"ExecutionParams.{name}")
        check_float(self.posture_weight, "ExecutionParams.posture_weight", allow_zero=True)
        check_int(self.substeps, "ExecutionParams.substeps")


@dataclasses.dataclass(frozen=True)
class NominalSettings:
    """Settings of the eq 4.9–4.12 potential fit of the two-step strategy (§5.2.1,
    :mod:`agents.lfd.two_step`); the thesis gives no values.

    * ``sigma_spacings``: the kernel length-scale ``σ`` (eq 4.9) is this many mean sample
      spacings of the nominal demonstration (the rule behind the LASA default of
      :func:`mjxrmp.learned.nominal_fit.fit_nominal_potential`, "σ a few sample spacings"): 2
      spacings give ``σ ≈ 2 cm`` on the Franka data at ``dt = 0.1 s`` (spacings ≈ 1 cm).
      Measured on the DTW nominal of each task (centre point, whole set), the fitted
      ``−∇Φ(ζ_t)`` matches ``ζ̇_t`` with relative error 0.20–0.26 (mean cosine 0.92–0.95) at
      ``σ = 2 cm``, against 0.24–0.37 at 3 cm and 0.85–1.2 at 3 cm with ``η = 50``.
    * ``eta``: ``η`` of eq 4.11; ``1/η = 10 cm`` is about a tenth of the demonstrated extent
      (0.4–0.8 m), the rule behind LASA's ``η = 10`` on its unit workspace. Larger values fit
      worse (relative error 0.5–0.99 at ``η = 50``); ``η`` between 3 and 10 differ by < 0.06.
    * ``lam``: ``λ`` of eq 4.12, the library default ``1e-3`` (biases come out ≈ 0.1–0.3, so
      the regulariser is small against the velocity fit).
    * ``goal_constraint``: handling of ``∇Φ(ζ_T) = 0``, see
      :func:`mjxrmp.learned.nominal_fit.fit_biases`.
    """

    sigma_spacings: float = 2.0
    eta: float = 10.0
    lam: float = 1e-3
    goal_constraint: str = "auto"

    def __post_init__(self) -> None:
        for name in ("sigma_spacings", "eta", "lam"):
            check_float(getattr(self, name), f"NominalSettings.{name}")
        check_choice(self.goal_constraint, "NominalSettings.goal_constraint",
                     ("auto", "penalty", "none"))
