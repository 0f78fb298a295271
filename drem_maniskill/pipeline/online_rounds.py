"""Policy rounds inside one SAC run (beyond the paper): the DREM reward fine-tuned on the run's own paid failures.

The offline rounds (``pipeline.policy_rounds``) train a policy to the end, label the failed states the reward paid like
the goal, fine-tune the reward and train the next policy from scratch; each next policy found the next such state. Here
the same rule runs every ``update_every`` env steps of one run, as VICE-RAQ updates its classifier:

- every step's reward inputs are kept (at the model's image size) with what the reward paid;
- an episode that ends without success gives its states paid at least ``trap_share`` of the goal's ``R = 1`` as traps;
- an update labels up to ``max_negatives`` of them at the tree's start depth (``RoundsConfig.trap_label = "start"``),
  repeated to ``min_share`` of the tree's nodes, fine-tunes the reward ``iterations`` steps on them, the earlier
  updates' traps and the tree (``train_reward.fine_tune``, the tree loaded once per run), and swaps the new reward
  into the training and evaluation envs;
- ``relabel`` pays the replay buffer's kept transitions again with the new reward, so the critic meets the cut at once
  rather than after the buffer has turned over.

A policy also fails where the reward stops rising short of the goal, paid less than ``trap_share``: a plateau the trap
rule cannot see. With ``stall_window > 0`` an episode without success whose best pay in its last ``stall_window`` share
of steps beats its best before by less than ``stall_rise`` stalled there (``policy_rounds.stalled_steps``), and those
steps join the update too, labelled at the start depth (``stall_label = "start"``: where a failed episode comes to rest
is no progress) or ``eps + 1`` beyond the nearest tree depth the current reward pays no more than it pays the step
(``"depth"``: the offline rounds' ``stall_depth``, so each update lowers a stall by one neighbourhood).

Each update's negatives and checkpoint are files under ``work``; the state (``state_dict``) names them, so a resumed run
goes on from the last finished update. Transitions stepped before a resume are not kept, and are not paid again.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import gymnasium as gym
import numpy as np
import torch

from drem_maniskill.drem.checkpoint import resolve_checkpoint
from drem_maniskill.drem.reward import DREM_FORMS, DREMReward
from drem_maniskill.pipeline.dataset import resize_images
from drem_maniskill.pipeline.negatives import write_negatives
from drem_maniskill.pipeline.policy_rounds import paid_by_depth, stall_depth, stalled_steps
from drem_maniskill.rl.rewards import REWARDS, RewardSpec, drem_make
from drem_maniskill.utils.checks import check_fraction


STALL_LABELS = ("start", "depth")


@dataclass
class OnlineRoundsConfig:
    """What ``reward_kwargs`` of a ``drem-rounds`` run set (``train-policy --reward-kwargs``)."""

    tree: Optional[str] = None
    """The progress tree the reward was trained on; None: ``tree.h5`` beside the checkpoint (a build's folder)."""
    update_every: int = 5_000
    """Env steps between updates."""
    iterations: int = 500
    """Fine-tuning iterations per update."""
    trap_share: float = 0.8
    """A failed episode's state is a trap when paid at least this share of the goal's ``R = 1`` (check-reward's
    rule)."""
    max_negatives: int = 500
    """At most this many traps per update, evenly spread over those found."""
    min_share: float = 0.005
    """Each update's traps are repeated in the fine-tuning's nodes until they make up at least this share of the tree's
    nodes: a handful among 100,000 nodes would hardly be sampled (an offline round's 300 among 50,000 cut their pay
    from 0.98 to 0.36)."""
    keep: int = 50_000
    """The last this many transitions are kept for ``relabel`` (about 25 kB each at 64 px, two cameras)."""
    stall_window: float = 0.0
    """The share of a failed episode's last steps searched for a stall; 0: stalls are not looked for."""
    stall_rise: float = 0.02
    """A failed episode stalled when its best pay in the window beats its best before it by less than this."""
    stall_label: str = "start"
    """A stalled step's label: ``"start"``, the tree's start depth; ``"depth"``, ``eps + 1`` beyond the nearest depth
    the reward pays no more than it pays the step."""

    def __post_init__(self):
        check_fraction("trap_share", self.trap_share, "the goal's pay")
        if not 0 <= self.stall_window < 1:
            raise ValueError(f"stall_window = {self.stall_window} is a share of an episode's steps: give one in [0, 1)")
        if self.stall_label not in STALL_LABELS:
            raise ValueError(f"stall_label = {self.stall_label!r}: give one of {STALL_LABELS}")
        if not 0 <= self.min_share < 1:
            raise ValueError(f"min_share = {self.min_share} is a share of the tree's nodes: give one in [0, 1)")
        for name in ("update_every", "iterations", "max_negatives", "keep"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} = {getattr(self, name)} must be at least 1")


class OnlineRounds(gym.Wrapper):
    """A ``drem`` env whose reward learns from the run's failures; the ``LearnedReward`` of ``drem-rounds``."""

    def __init__(self, env: gym.Env, config: OnlineRoundsConfig, work, state: Optional[dict] = None):
        super().__init__(env)
        u = env.unwrapped
        if getattr(u, "drem_reward", None) is None:
            raise ValueError("drem-rounds wraps an env made with reward_mode='drem'")
        self.config, self.work = config, Path(work)
        self.update_every = int(config.update_every)
        self.shift = DREM_FORMS[u.drem_form]
        self.checkpoint = str(resolve_checkpoint(u.env_id, u.drem_checkpoint))
        self.tree = config.tree or str(Path(self.checkpoint).parent / "tree.h5")
        if not Path(self.tree).is_file():
            raise FileNotFoundError(f"drem-rounds fine-tunes the reward on its tree, and {self.tree} is not a file: "
                                    "pass reward_kwargs tree=<the build's tree.h5>")
        model = u.drem_reward.model.config
        self.size, self.cameras, self.has_ft = model.image_size, list(model.cameras), "ft" in model.modalities
        n, cap = u.num_envs, int(config.keep)
        self.images = {c: torch.zeros(cap, n, self.size, self.size, 3, dtype=torch.uint8) for c in self.cameras}
        self.ft = torch.zeros(cap, n, 8, 6)
        self.paid = torch.zeros(cap, n)
        self.steps = 0  # transitions recorded: one per env.step, the replay buffer's position
        self.kept_from = 0  # the first step still held (later than any step before a resume)
        self.episode_start = np.zeros(n, np.int64)  # per env: the first step of its open episode
        self.success = np.zeros(n, bool)
        self.pending: list = []  # (step, env, stalled) of failed episodes' traps and stalls, not yet labelled
        self.updates, self.negatives, self.eval_envs = 0, [], []
        self.found, self._data, self.label, self._changed, self.repeats = 0, None, None, False, []
        if state is not None:
            self.load_state_dict(state)

    # ------------------------------------------------------------------ recording
    def reset(self, **kwargs):
        """Reset; the reset envs' episodes end here (``options['env_idx']`` where only some are)."""
        idx = (kwargs.get("options") or {}).get("env_idx")
        ended = range(len(self.success)) if idx is None else [int(i) for i in torch.as_tensor(idx).reshape(-1)]
        for i in ended:
            self._end_episode(i)
        return self.env.reset(**kwargs)

    def _end_episode(self, i: int) -> None:
        if not self.success[i]:
            steps = torch.arange(max(int(self.episode_start[i]), self.kept_from), self.steps)
            paid = self.paid[steps % self.config.keep, i]
            trap = paid >= self.config.trap_share
            self.pending += [(int(t), i, False) for t in steps[trap]]
            if self.config.stall_window > 0 and len(steps):
                window = stalled_steps(paid.tolist(), self.config.stall_window, self.config.stall_rise)
                self.pending += [(int(steps[t]), i, True) for t in window if not trap[t]]
        self.episode_start[i], self.success[i] = self.steps, False

    def step(self, action):
        """Step, and keep the state's reward inputs and what it was paid."""
        obs, reward, terminated, truncated, info = self.env.step(action)
        inputs = self.env.unwrapped.drem_reward.last_inputs
        slot = self.steps % self.config.keep
        for c in self.cameras:
            self.images[c][slot] = resize_images(inputs[c].cpu(), self.size)
        if self.has_ft:
            self.ft[slot] = inputs["ft"].cpu().float()
        self.paid[slot] = torch.as_tensor(reward).reshape(-1).cpu().float() - self.shift
        self.success |= torch.as_tensor(info["success"]).reshape(-1).cpu().numpy().astype(bool)
        self.steps += 1
        return obs, reward, terminated, truncated, info

    def _rows(self, picks: list) -> list:
        rows = []
        for t, i in picks:
            slot = t % self.config.keep
            inputs = {c: self.images[c][slot, i][None].clone() for c in self.cameras}
            inputs["ft"] = self.ft[slot, i][None].clone()
            rows.append((inputs, float(self.paid[slot, i]), i, t))
        return rows

    # ------------------------------------------------------------------ learning
    def update(self) -> dict:
        """Label the traps found since the last update, fine-tune the reward on them, swap it into the envs."""
        from drem_maniskill.drem.checkpoint import load_checkpoint
        from drem_maniskill.pipeline.train_reward import fine_tune, train_config_of

        pending = [p for p in self.pending if p[0] >= max(self.kept_from, self.steps - self.config.keep)]
        self.pending = []
        if not pending:
            return dict(traps=0, updates=self.updates)
        if len(pending) > self.config.max_negatives:
            picks = np.linspace(0, len(pending) - 1, self.config.max_negatives).round().astype(int)
            pending = [pending[j] for j in picks]
        config = train_config_of(load_checkpoint(self.checkpoint)[0])
        data = self._tree_data(config)
        k = self.updates + 1
        rows = self._rows([(t, i) for t, i, _ in pending])
        stalled = np.array([s for *_, s in pending], bool)
        labels = np.full(len(rows), self.label, np.int64)
        if stalled.any() and self.config.stall_label == "depth":
            labels[stalled] = self._stall_depths([r for (_, r, _, _), s in zip(rows, stalled) if s], config)
        folder = self.work / f"update_{k}"
        folder.mkdir(parents=True, exist_ok=True)
        write_negatives(folder / "negatives.h5", rows, labels, self.cameras, self.has_ft)
        repeat = max(1, int(np.ceil(self.config.min_share * self.tree_nodes / len(rows))))
        data.add_negatives([folder / "negatives.h5"], config.model, repeat=repeat)
        tuned = dataclasses.replace(config, iterations=self.config.iterations, seed=config.seed + k)
        before = float(np.mean([r for _, r, _, _ in rows]))
        record = dict(update=k, steps=self.steps, traps=len(rows), stalled=int(stalled.sum()), trap_label=self.label,
                      paid_before=round(before, 4), repeat=repeat)
        if stalled.any():
            record["stall_labels"] = [int(labels[stalled].min()), int(labels[stalled].max())]
        path = fine_tune(data, self.checkpoint, tuned, folder / "drem.pt", dict(online_rounds=record))
        self.negatives, self.checkpoint, self.updates = [*self.negatives, str(folder / "negatives.h5")], path, k
        self.repeats.append(repeat)
        self.found += len(rows)
        self._swap_reward()
        self._changed = True
        after = float(self._pay({c: torch.cat([x[c] for x, *_ in rows]) for c in rows[0][0]}).mean())
        return dict(traps=len(rows), stalled=int(stalled.sum()), paid_before=before, paid_after=after, updates=k)

    def _stall_depths(self, paid: list, config) -> np.ndarray:
        """``policy_rounds.stall_depth`` of each stalled step paid ``paid``, on the current reward's pay by depth."""
        depths, curve = paid_by_depth(self.env.unwrapped.drem_reward, self._data)
        return np.array([stall_depth(r, depths, curve, config.eps) for r in paid], np.int64)

    def _tree_data(self, config):
        """The tree (and every earlier update's traps) as training data for ``config`` (a ``TrainConfig``), loaded at
        the first update."""
        from drem_maniskill.pipeline.dataset import TreeDataset
        from drem_maniskill.pipeline.tree.tree_file import start_depth

        if self._data is None:
            self.label = start_depth(Path(self.tree))
            if self.label is None:
                raise ValueError(f"{self.tree} never reached the start region, the depth drem-rounds labels traps at: "
                                 "sample it further")
            data = TreeDataset(self.tree, config.model, travel=config.travel_labels)
            self.tree_nodes = len(data.depth)
            for path, repeat in zip(self.negatives, self.repeats):
                data.add_negatives([path], config.model, repeat=repeat)
            self._data = data
        return self._data

    def _swap_reward(self) -> None:
        for env in [self.env, *self.eval_envs]:
            u = env.unwrapped
            u.drem_reward = DREMReward.from_checkpoint(self.checkpoint, env=u)
            u.drem_checkpoint = self.checkpoint

    @torch.no_grad()
    def _pay(self, batch: dict, chunk: int = 512) -> torch.Tensor:
        reward = self.env.unwrapped.drem_reward
        n = len(next(iter(batch.values())))
        device = next(reward.parameters()).device
        return torch.cat([reward({k: v[s:s + chunk].to(device) for k, v in batch.items()}).cpu()
                          for s in range(0, n, chunk)])

    def relabel(self, replay_buffer) -> int:
        """After an update that changed the reward, pay the kept transitions again in ``replay_buffer`` (SB3's, filled
        one row per step since this run began); returns how many rows. A buffer out of step with the recorded steps
        is left as it is."""
        size = replay_buffer.buffer_size
        changed, self._changed = self._changed, False
        if not changed or replay_buffer.pos != self.steps % size:
            return 0
        first = max(self.kept_from, self.steps - self.config.keep, self.steps - size)
        steps = torch.arange(first, self.steps)
        if not len(steps):
            return 0
        slots = steps % self.config.keep
        n = self.paid.shape[1]
        batch = {c: self.images[c][slots].flatten(0, 1) for c in self.cameras}
        batch["ft"] = self.ft[slots].flatten(0, 1)
        paid = self._pay(batch).reshape(len(steps), n)
        self.paid[slots] = paid
        replay_buffer.rewards[(steps % size).numpy()] = (paid + self.shift).numpy().astype(replay_buffer.rewards.dtype)
        return len(steps) * n

    # ------------------------------------------------------------------ the run's interface
    def evaluation_env(self, env: gym.Env) -> gym.Env:
        """``env`` (a ``drem`` env), paid by this reward from now on, learning nothing from it."""
        self.eval_envs.append(env)
        if self.updates:
            self._swap_reward()
        return env

    def state_dict(self) -> dict:
        """The updates made, their files, and the step count the replay buffer is aligned with."""
        return dict(config=dataclasses.asdict(self.config), updates=self.updates, checkpoint=self.checkpoint,
                    negatives=list(self.negatives), repeats=list(self.repeats), steps=self.steps, found=self.found)

    def load_state_dict(self, state: dict) -> None:
        """Go on from ``state``: the last update's reward, counting steps on from where it was saved."""
        for path in (state["checkpoint"], *state["negatives"]):
            if not Path(path).is_file():
                raise FileNotFoundError(f"the drem-rounds state names {path}, which is gone: rerun without resuming")
        self.updates, self.checkpoint = int(state["updates"]), state["checkpoint"]
        self.negatives, self.found = list(state["negatives"]), int(state.get("found", 0))
        self.repeats = list(state.get("repeats", [1] * len(self.negatives)))
        self.steps = self.kept_from = int(state["steps"])
        if self.updates:
            self._swap_reward()


def online_rounds_learner(env: gym.Env, task: str, seed: int, options: dict, state: Optional[dict],
                          make_kwargs: dict, run_dir: Optional[Path] = None) -> OnlineRounds:
    """``OnlineRounds`` around the ``drem`` training env (``RewardSpec.learner``); its files in
    ``<run>/drem-rounds/``."""
    work = Path(run_dir) if run_dir is not None else Path("outputs") / "drem-rounds" / task / f"seed{seed}"
    return OnlineRounds(env, OnlineRoundsConfig(**options), work / "drem-rounds", state)


# A reward of the run's table (``rl.rewards.REWARDS``), registered from this layer because it trains the reward:
# ``import drem_maniskill`` imports this module, so every process that trains with it knows the name.
REWARDS["drem-rounds"] = RewardSpec(
    "DREM fine-tuned during the run on its failed states paid like the goal (not in the paper; docs/rewards.md)",
    drem_make(False), checkpoint=True, learner=online_rounds_learner)
