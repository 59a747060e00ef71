"""Animated GIFs of one rollout of a reaching environment (needs matplotlib: ``[plots]`` extra).

3-link: top-down view with links, control points, goal and obstacle circles. Franka: 3-D view
with the link chain as line segments, control points as spheres (markers scaled by radius),
ball obstacles (wireframes) and the goal. Figures are built with matplotlib's object API
(no pyplot, no global backend switch). ``scripts/render.py`` is the command line.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import numpy as np
from brax.envs.base import Env, State
from matplotlib import animation
from matplotlib.figure import Figure
from matplotlib.patches import Circle

from envs.evaluate import frozen_step, hand_designed_policy
from envs.registry import make
from mjxrmp.robots import franka, three_link

#: Franka frames joined by the drawn link chain.
_CHAIN = ("link0", "link1", "link2", "link3", "link4", "link5", "link6", "link7", "link8",
          "hand", "grasp_target")
#: Per-step entries of a trajectory (subsampled for drawing); the others are per episode.
_PER_STEP = ("q", "done", "goal_distance")

__all__ = ["animate", "render_rollout", "save_gif", "trajectory"]


def trajectory(env: Env, policy: Callable[[State], jax.Array], key: jax.Array,
               steps: int) -> dict[str, Any]:
    """One episode of ``policy(state) -> action`` from ``env.reset(key)`` (frozen after done):
    joint positions ``q (steps + 1, dof)``, done flags, goal distances, goal, obstacles
    (``centers``, ``radii`` of the active obstacles) and the episode return."""
    step = frozen_step(env, policy)

    @jax.jit
    def run(key):
        state = env.reset(key)

        def body(s, _):
            new = step(s)
            return new, (new.pipeline_state.qpos, new.done, new.metrics["goal_distance"])

        final, traj = jax.lax.scan(body, state, None, length=steps)
        return state, final, traj

    first, final, (qs, done, dist) = run(key)
    q0 = np.asarray(first.pipeline_state.qpos)[None]
    active = np.asarray(first.info["obstacles"].active) > 0  # padding slots are not drawn
    return {
        "q": np.concatenate([q0, np.asarray(qs)]),
        "done": np.concatenate([[0.0], np.asarray(done)]),
        "goal_distance": np.concatenate([[np.nan], np.asarray(dist)]),
        "goal": np.asarray(first.info["goal"]),
        "centers": np.asarray(first.info["obstacles"].center)[active],
        "radii": np.asarray(first.info["obstacles"].radius)[active],
        "return": float(final.info["episode_return"]),
    }


def _caption(data: dict, i: int) -> str:
    return (f"step {i}  goal dist {data['goal_distance'][i]:.3f}"
            + ("  (done)" if data["done"][i] else ""))


def _animate_three_link(data: dict, fps: int) -> tuple[Figure, animation.FuncAnimation]:
    fig = Figure(figsize=(5, 5))
    ax = fig.add_subplot()
    ax.set_xlim(-1.0, 1.0)
    ax.set_ylim(-1.0, 1.0)
    ax.set_aspect("equal")
    for c, r in zip(data["centers"], data["radii"], strict=True):
        ax.add_patch(Circle(c, r, color="tab:red", alpha=0.6))
    ax.add_patch(Circle((0, 0), 0.75, fill=False, ls=":", color="gray"))
    ax.plot(*data["goal"], marker="*", ms=14, color="tab:green")
    (arm,) = ax.plot([], [], "-o", lw=3, color="tab:blue")
    points = ax.scatter([], [], s=20, color="navy")
    title = ax.set_title("")
    jp = np.asarray(jax.jit(jax.vmap(three_link.joint_positions))(data["q"]))
    cps = np.asarray(jax.jit(jax.vmap(three_link.control_points))(data["q"]))

    def frame(i):
        arm.set_data(jp[i, :, 0], jp[i, :, 1])
        points.set_offsets(cps[i])
        title.set_text(_caption(data, i))
        return arm, points, title

    return fig, animation.FuncAnimation(fig, frame, frames=len(jp), interval=1000 / fps)


def _sphere(ax, c, r, **kw) -> None:
    u, v = np.mgrid[0 : 2 * np.pi : 12j, 0 : np.pi : 8j]
    ax.plot_wireframe(c[0] + r * np.cos(u) * np.sin(v), c[1] + r * np.sin(u) * np.sin(v),
                      c[2] + r * np.cos(v), **kw)


def _animate_franka(data: dict, fps: int) -> tuple[Figure, animation.FuncAnimation]:
    fig = Figure(figsize=(6, 6))
    ax = fig.add_subplot(projection="3d")
    frames = jax.jit(jax.vmap(franka.link_frames))(data["q"])
    chain = np.stack([np.asarray(frames[n][1]) for n in _CHAIN], axis=1)
    cps = np.asarray(jax.jit(jax.vmap(franka.control_points))(data["q"]))
    sizes = 3000 * np.asarray(franka.CONTROL_POINT_RADII) ** 2 * 40
    title = ax.set_title("")

    def frame(i):
        ax.cla()
        ax.set_xlim(-0.4, 0.9)
        ax.set_ylim(-0.65, 0.65)
        ax.set_zlim(0.0, 1.1)
        for c, r in zip(data["centers"], data["radii"], strict=True):
            _sphere(ax, c, r, color="tab:red", lw=0.5)
        ax.scatter(*data["goal"], marker="*", s=200, color="tab:green")
        ax.plot(chain[i, :, 0], chain[i, :, 1], chain[i, :, 2], "-", lw=3, color="tab:blue")
        ax.scatter(cps[i, :, 0], cps[i, :, 1], cps[i, :, 2], s=sizes, alpha=0.3, color="navy")
        ax.set_title(_caption(data, i))
        return (title,)

    return fig, animation.FuncAnimation(fig, frame, frames=len(chain), interval=1000 / fps)


def animate(data: dict, robot_name: str, fps: int = 20) -> tuple[Figure, animation.FuncAnimation]:
    """``(figure, animation)`` of a :func:`trajectory` of the ``"three_link"`` or ``"franka"``
    robot, one frame per entry of ``data["q"]``."""
    if robot_name == "three_link":
        return _animate_three_link(data, fps)
    if robot_name == "franka":
        return _animate_franka(data, fps)
    raise ValueError(f"render supports the 3-link and Franka robots, got {robot_name!r}")


def save_gif(data: dict, robot_name: str, path: str, every: int = 3, fps: int = 20) -> int:
    """Write the animation of every ``every``-th control step of ``data`` (a
    :func:`trajectory`) to the GIF ``path``; returns the number of frames."""
    sub = {k: (v[::every] if k in _PER_STEP else v) for k, v in data.items()}
    _, anim = animate(sub, robot_name, fps)
    anim.save(path, writer=animation.PillowWriter(fps=fps))
    return len(sub["q"])


def render_rollout(env_name: str, path: str, seed: int = 0, steps: int = 300, every: int = 3,
                   fps: int = 20) -> dict[str, Any]:
    """Roll out the hand-designed RMP² policy on ``envs.make(env_name)`` from
    ``PRNGKey(seed)`` for ``steps`` control steps and write it as a GIF (:func:`save_gif`).
    Returns the :func:`trajectory` with ``frames`` (the number of GIF frames) added."""
    env = make(env_name)
    if env.robot_name not in ("three_link", "franka"):
        raise ValueError(f"render supports the 3-link and Franka environments, got {env_name}")
    data = trajectory(env, hand_designed_policy(env), jax.random.PRNGKey(seed), steps)
    return {**data, "frames": save_gif(data, env.robot_name, path, every, fps)}
