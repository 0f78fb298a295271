"""How much of a reward's rise is left on the socket's face, by distance from the opening: the measure of the face trap.

    .venv/bin/python experiments/face_profile.py --task USBInsertion-v1 \
        --checkpoint drem=rewards/USBInsertion-v1/drem.pt \
        --checkpoint drem-image=rewards/USBInsertion-v1/drem_image.pt \
        --out docs/results/face_profile/USBInsertion-v1.json --plot docs/images/results/face_profile_USBInsertion-v1.png

SAC trained on a reward that pays the part pressed on the face beside the opening nearly what it
pays an insertion stops on the face (docs/results.md). The examination's one "pressed
3 mm beside" position says that the face is over-paid, not whether the reward still leads along
the face to the opening, which is what a policy on the face needs. This holds the tip (upright,
``HoldPolicy``) pressed on the face and 2 mm above it at growing distances from the axis, in two
directions, on held-out seeds with the task's colours and placements, and reads every named DREM
checkpoint and the task's ``engineered`` reward there. Each value is also given as the fraction of
the reward's rise from the episode's start to a finished insertion that is still to go:
``(r_inserted - r) / (r_inserted - r_start)``, 0 at the goal and 1 at the start, comparable
across rewards of any sign and scale. The summary per reward (``evaluate.measures.face_lead``): the
fraction still to go on the face near the opening, and the *lead*, the reward's rise per millimetre
towards the opening in units of its spread across episodes.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

CAMERAS = ("fixed_camera", "wrist_camera")
OFFSETS_MM = (0, 1, 2, 3, 4, 6, 8, 12)
HEIGHTS = {"pressed": None, "2 mm above": 0.002}  # None: PRESS_DEPTH below the top face


def main() -> None:
    """Hold, score, print and write the JSON and the plot."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", required=True)
    p.add_argument("--checkpoint", action="append", required=True, help="NAME=PATH of a DREM checkpoint")
    p.add_argument("--seeds", type=int, default=5, help="held-out seeds 0..N-1")
    p.add_argument("--out", help="JSON to write")
    p.add_argument("--plot", help="PNG to write")
    args = p.parse_args()

    import gymnasium as gym

    import drem_maniskill  # noqa: F401  (registers the tasks)
    from drem_maniskill.drem.reward import DREMReward
    from drem_maniskill.evaluate.measures import FACE_LEAD_RANGE_MM, face_lead
    from drem_maniskill.evaluate.probes import HOLD_STEPS
    from drem_maniskill.experts import get_policy, rollout
    from drem_maniskill.experts.scripted import PRESS_DEPTH, HoldPolicy
    from drem_maniskill.utils.cameras import camera_images

    torch.set_num_threads(1)
    env = gym.make(args.task, obs_mode="state_dict", reward_mode="engineered")
    u = env.unwrapped
    names = dict(c.split("=", 1) for c in args.checkpoint)
    drem = {name: DREMReward.from_checkpoint(path, env=u) for name, path in names.items()}

    def score(obs, engineered: float) -> dict:
        images = camera_images(u, obs, CAMERAS)
        seen = {"sensor_data": {uid: {"rgb": img} for uid, img in images.items()}}
        return {"engineered": engineered, **{n: float(r.reward(u, seen)[0]) for n, r in drem.items()}}

    def start_score(seed: int) -> dict:
        obs, _ = env.reset(seed=seed)
        action = torch.zeros(env.action_space.shape)
        obs, reward, *_ = env.step(action)  # one still step: the first reward an episode pays
        return score(obs, float(torch.as_tensor(reward).reshape(-1)[0]))

    seeds = range(args.seeds)
    start = [start_score(s) for s in seeds]
    inserted = []
    for s in seeds:
        ep = rollout(env, get_policy("expert", env, seed=s), s, stop_on_success=False)
        if ep.success:
            inserted.append(score(ep.obs, ep.rewards[-1]))
    rewards = ["engineered", *names]
    r_start = {n: float(np.mean([x[n] for x in start])) for n in rewards}
    r_ins = {n: float(np.mean([x[n] for x in inserted])) for n in rewards}

    positions = []
    for height, z in HEIGHTS.items():
        for axis in ("x", "y"):
            for mm in OFFSETS_MM:
                if axis == "y" and mm == 0:
                    continue  # the same place as x, 0
                target = [0.0, 0.0, -PRESS_DEPTH if z is None else z]
                target[0 if axis == "x" else 1] = mm / 1000
                got, tips = [], []
                for s in seeds:
                    ep = rollout(env, HoldPolicy(env, target), s, HOLD_STEPS, stop_on_success=False)
                    got.append(score(ep.obs, ep.rewards[-1]))
                    tips.append(u.tip_pose_in_socket().p[0].cpu().numpy() * 1000)
                tip = np.mean(tips, axis=0)
                row = dict(height=height, axis=axis, offset_mm=mm, tip_mm=[round(float(t), 2) for t in tip],
                           inserted=bool(tip[2] < -1.0 and mm == 0))
                for n in rewards:
                    vals = [g[n] for g in got]
                    row[n] = dict(values=vals, mean=float(np.mean(vals)), std=float(np.std(vals)),
                                  to_go=float((r_ins[n] - np.mean(vals)) / (r_ins[n] - r_start[n])))
                positions.append(row)
                print(f"{height:>10} {axis} {mm:>2} mm  tip {row['tip_mm']}  "
                      + "  ".join(f"{n} {row[n]['mean']:.3f} (to go {row[n]['to_go']:.2f})" for n in rewards),
                      flush=True)

    pressed = [r for r in positions if r["height"] == "pressed"]
    lead = {n: face_lead(pressed, n, r_start[n], r_ins[n]) for n in rewards}
    for n, x in lead.items():
        print(f"{n}: on the face {FACE_LEAD_RANGE_MM[0]}-{FACE_LEAD_RANGE_MM[1]} mm from the axis, to go "
              f"{x['to_go']:.2f}, order {x['order']:.2f}, lead {x['lead']:.2f} spreads per mm (slope "
              f"{x['slope_per_mm']:.4f}/mm, spread {x['spread']:.3f}; between episodes {x['between_episodes']:.3f})")
    result = dict(task=args.task, seeds=args.seeds, checkpoints=names, press_depth_mm=PRESS_DEPTH * 1000,
                  start=r_start, inserted=r_ins, inserted_episodes=len(inserted), face_lead=lead, positions=positions)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
    if args.plot:
        _plot(result, rewards, args.plot)


def _plot(result: dict, rewards: list, path: str) -> None:
    """Fraction of the rise still to go against the distance from the axis, one panel per height."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(HEIGHTS), figsize=(5 * len(HEIGHTS), 3.6), sharey=True)
    for ax, height in zip(axes, HEIGHTS):
        for n in rewards:
            for axis, style in (("x", "-o"), ("y", "--s")):
                rows = [r for r in result["positions"]
                        if r["height"] == height and (r["axis"] == axis or r["offset_mm"] == 0)]
                ax.plot([float(np.hypot(*r["tip_mm"][:2])) for r in rows], [r[n]["to_go"] for r in rows], style, ms=3,
                        label=f"{n} ({axis})", color=f"C{rewards.index(n)}")
        ax.axhline(0, color="k", lw=0.5)
        ax.set_title(f"{result['task']}: tip {'pressed on' if height == 'pressed' else height} the face")
        ax.set_xlabel("distance of the tip from the opening's axis, reached (mm)")
    axes[0].set_ylabel("fraction of the rise still to go\n(0 inserted, 1 start)")
    axes[-1].legend(fontsize=7)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    print(f"plot: {path}")


if __name__ == "__main__":
    main()
