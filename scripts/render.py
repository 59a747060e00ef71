"""Render one rollout of the hand-designed RMP² policy as an animated GIF.

3-link: top-down view with links, control points, goal and obstacle circles. Franka: 3-D
matplotlib view with the link chain as line segments, control points as spheres (markers
scaled by radius), ball obstacles (wireframes) and the goal.

    python -m scripts.render --env three_link/env3 --seed 0 --steps 300 --out rollout.gif
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax
import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from matplotlib import animation

import envs
from envs import evaluate
from mjxrmp.robots import franka, three_link

_CHAIN = ("link0", "link1", "link2", "link3", "link4", "link5", "link6", "link7", "link8",
          "hand", "grasp_target")


def trajectory(env, policy, key: jax.Array, steps: int) -> dict:
    """One episode of ``policy(state) -> action`` from ``env.reset(key)`` (frozen after done):
    joint positions, done flags, goal distances, goal, obstacles and the episode return."""

    @jax.jit
    def run(key):
        state = env.reset(key)

        def body(s, _):
            new = env.step(s, policy(s))
            new = jax.tree.map(lambda a, b: jax.numpy.where(s.done > 0, b, a), new, s)
            return new, (new.pipeline_state.qpos, new.done, new.metrics["goal_distance"])

        final, traj = jax.lax.scan(body, state, None, length=steps)
        return state, final, traj

    first, final, (qs, done, dist) = run(key)
    q0 = np.asarray(first.pipeline_state.qpos)[None]
    return {
        "q": np.concatenate([q0, np.asarray(qs)]),
        "done": np.concatenate([[0.0], np.asarray(done)]),
        "goal_distance": np.concatenate([[np.nan], np.asarray(dist)]),
        "goal": np.asarray(first.info["goal"]),
        "centers": np.asarray(first.info["obstacles"].center),
        "radii": np.asarray(first.info["obstacles"].radius),
        "return": float(final.info["episode_return"]),
    }


def rollout(env, seed: int, steps: int) -> dict:
    """:func:`trajectory` of the hand-designed RMP² policy from ``PRNGKey(seed)``."""
    return trajectory(env, evaluate.hand_designed_policy(env), jax.random.PRNGKey(seed), steps)


def _animate_three_link(data: dict, fps: int):
    fig, ax = plt.subplots(figsize=(5, 5))
    ax.set_xlim(-1.0, 1.0)
    ax.set_ylim(-1.0, 1.0)
    ax.set_aspect("equal")
    for c, r in zip(data["centers"], data["radii"], strict=True):
        ax.add_patch(plt.Circle(c, r, color="tab:red", alpha=0.6))
    ax.add_patch(plt.Circle((0, 0), 0.75, fill=False, ls=":", color="gray"))
    ax.plot(*data["goal"], marker="*", ms=14, color="tab:green")
    (arm,) = ax.plot([], [], "-o", lw=3, color="tab:blue")
    points = ax.scatter([], [], s=20, color="navy")
    title = ax.set_title("")
    jp = jax.jit(jax.vmap(three_link.joint_positions))(data["q"])
    cps = jax.jit(jax.vmap(three_link.control_points))(data["q"])
    jp, cps = np.asarray(jp), np.asarray(cps)

    def frame(i):
        arm.set_data(jp[i, :, 0], jp[i, :, 1])
        points.set_offsets(cps[i])
        title.set_text(f"step {i}  goal dist {data['goal_distance'][i]:.3f}"
                       + ("  (done)" if data["done"][i] else ""))
        return arm, points, title

    return fig, animation.FuncAnimation(fig, frame, frames=len(jp), interval=1000 / fps)


def _sphere(ax, c, r, **kw):
    u, v = np.mgrid[0 : 2 * np.pi : 12j, 0 : np.pi : 8j]
    ax.plot_wireframe(c[0] + r * np.cos(u) * np.sin(v), c[1] + r * np.sin(u) * np.sin(v),
                      c[2] + r * np.cos(v), **kw)


def _animate_franka(data: dict, fps: int):
    fig = plt.figure(figsize=(6, 6))
    ax = fig.add_subplot(projection="3d")
    frames_fn = jax.jit(jax.vmap(franka.link_frames))
    frames = frames_fn(data["q"])
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
        ax.set_title(f"step {i}  goal dist {data['goal_distance'][i]:.3f}"
                     + ("  (done)" if data["done"][i] else ""))
        return (title,)

    return fig, animation.FuncAnimation(fig, frame, frames=len(chain), interval=1000 / fps)


def main(argv=None) -> str:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--env", default="three_link/env3",
                   help="three_link/env1|env2|env3 or franka")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--every", type=int, default=3, help="draw every n-th control step")
    p.add_argument("--fps", type=int, default=20)
    p.add_argument("--out", default="rollout.gif")
    args = p.parse_args(argv)
    env = envs.make(args.env)
    if env.robot_name not in ("three_link", "franka"):
        raise ValueError(f"render supports the 3-link and Franka environments, got {args.env}")
    data = rollout(env, args.seed, args.steps)
    sub = {k: (v[:: args.every] if k in ("q", "done", "goal_distance") else v)
           for k, v in data.items()}
    anim_fn = _animate_three_link if env.robot_name == "three_link" else _animate_franka
    fig, anim = anim_fn(sub, args.fps)
    anim.save(args.out, writer=animation.PillowWriter(fps=args.fps))
    plt.close(fig)
    print(f"wrote {args.out}: {len(sub['q'])} frames, return {data['return']:.1f}, "
          f"final goal distance {data['goal_distance'][-1]:.3f}")
    return args.out


if __name__ == "__main__":
    main()
