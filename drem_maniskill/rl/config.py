"""Configuration of a SAC run (``train-policy``): one dataclass, four presets, saved as JSON in the run dir."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from drem_maniskill.envs import is_insertion_task
from drem_maniskill.utils.checks import check_fraction

PRESETS = ("state", "light", "image", "paper")
# Episodes end at success, vector inputs normalised, half the action range: the setting where SAC learns the peg
# with engineered in all three seeds (docs/rl.md); the state and light presets.
LEARNABLE = dict(terminate_on_success=True, obs_norm=("state", "ft"), action_scale=0.5)


def native_bf16() -> bool:
    """Whether this CPU computes bfloat16 matrix products in hardware (AVX512-BF16 or AMX)."""
    import torch

    # Without them torch emulates bfloat16, many times slower than float32 (docs/rl.md, "Speed").
    # torch.cpu names these checks with an underscore.
    checks = ("_is_avx512_bf16_supported", "_is_amx_tile_supported")
    return any(getattr(torch.cpu, name, lambda: False)() for name in checks)


@dataclass
class RLConfig:
    """Everything a run needs; ``RLConfig.from_preset(name, **overrides)`` is the usual way to make one."""

    task: str = "PegInHole-v1"
    """Env id: one of ours or a ManiSkill task the reward fits."""
    reward: str = "drem"
    """A name of ``rl.rewards.REWARDS``."""
    algo: str = "sac"
    """A name of ``rl.algos.ALGOS``."""
    seed: int = 0
    """Training seed."""
    steps: int = 20_000
    """Environment steps, all envs together."""
    preset: str = "light"
    """The preset the run started from (``RLConfig.from_preset``)."""
    out: Optional[str] = None
    """Run dir; None: outputs/rl/<task>/<reward>/seed<S>."""

    # --- what the policy sees
    image_size: int = 32
    """Pixels of both cameras' images, area-downscaled from the 128 px render."""
    cameras: tuple = ("fixed_camera", "wrist_camera")
    """Camera uids the policy sees; none: a state-only policy."""
    policy_ft: Optional[bool] = True
    """Whether the policy gets the wrist F/T history; None: only with the drem reward, as the paper does."""
    policy_state: bool = True
    """Whether the policy gets qpos (9) and the TCP pose (7)."""
    policy_qvel: bool = False
    """Whether the policy also gets the joint velocities (9)."""
    policy_privileged: bool = False
    """Whether the policy gets the task's object poses, in runs without images.

    On our tasks the socket's pose (7); on ManiSkill's own tasks their state observation's ``obs["extra"]`` but the
    TCP pose (the cube's and the goal's, for instance)."""
    obs_norm: tuple = ()
    """Vector inputs (state, ft) normalised by running statistics in the network."""
    action_scale: float = 1.0
    """The policy's [-1, 1] as a fraction of the controller's range (2 cm, 0.1 rad per step)."""

    # --- the policy network (SB3 MultiInputPolicy with our extractor)
    cnn_channels: tuple = (16, 32, 32)
    """Channels of the stride-2 convs per camera."""
    camera_features: int = 64
    """Features per camera out of its CNN."""
    ft_features: int = 32
    """Features out of the F/T history's encoder."""
    net_arch: tuple = (256, 256)
    """Hidden layer widths of actor and critics."""
    share_features_extractor: bool = False
    """SB3's sharing: one extractor for actor and critics, trained by the actor loss."""
    shared_encoder: bool = True
    """One extractor for actor and critics, trained by the critic loss, the actor reading it detached.

    As ManiSkill's sac_rgbd.py and DrQ: per gradient step the CNNs run 2 forward and 1 backward passes,
    not 5 and 3."""

    # --- SAC (stable-baselines3)
    learning_rate: float = 3e-4
    """Adam's learning rate, actor and critics."""
    buffer_size: int = 50_000
    """Replay buffer capacity in transitions."""
    batch_size: int = 64
    """Transitions per gradient step; 64 small images keep the light preset's step about twice the env step."""
    learning_starts: int = 1_000
    """Env steps of random actions before the first gradient step."""
    train_freq: int = 1
    """Env steps between updates; the update ratio is gradient_steps / train_freq.

    Every preset takes 1: fewer updates per env step run faster but learn less (docs/rl.md, "Speed")."""
    gradient_steps: int = 1
    """Gradient steps per update."""
    gamma: float = 0.95
    """Discount; 50-step episodes give an effective horizon of about 20 steps."""
    tau: float = 0.005
    """Polyak factor of the target critics."""
    train_bf16: bool = False
    """SAC's gradient step under bfloat16 autocast (``rl.sac.SAC.train_bf16``).

    Faster on CPUs with AVX512-BF16 or AMX, far slower without; the state preset turns it on where
    ``native_bf16()``, its step being large matrix products (docs/rl.md, "Speed")."""
    overlap_env: bool = False
    """Step the training env in a child process while SAC's gradient step runs here.

    Each action comes from the policy one update older (``rl.vec_env.SubprocDictVecEnv``,
    ``rl.sac.SAC.train_while_env_steps``). A reward that learns from the run (VICE-RAQ) or an algorithm
    that cannot defer its step stays in this process (``overlap_env_used``)."""
    ent_coef: str = "auto"
    """SAC's entropy coefficient; auto: learned towards the target entropy."""
    terminate_on_success: bool = False
    """End a training episode at its first success (a terminal state)."""

    # --- environment
    num_envs: int = 1
    """Parallel envs (GPU sim)."""
    sim_backend: str = "cpu"
    """ManiSkill's sim backend: cpu or gpu."""
    env_kwargs: dict = field(default_factory=dict)
    """Extra gym.make keyword arguments."""
    device: str = "auto"
    """Torch device of SAC; auto: cuda when there is one."""
    threads: int = 1
    """Torch CPU threads; one is faster than two here, for the gradient step and the run (docs/rl.md, "Speed")."""

    # --- evaluation and checkpoints
    eval_every: int = 2_000
    """Env steps between evaluations and checkpoints."""
    eval_seed: int = 10_000
    """First seed of the held-out evaluation episodes."""
    eval_episodes: int = 10
    """Held-out episodes per evaluation."""

    # --- the reward
    reward_kwargs: dict = field(default_factory=dict)
    """Options passed to the reward's learner.

    vice: VICEConfig overrides, and goal_seeds: the expert episodes (seeds 0..n-1) whose successful
    images are the goals (default 10). drem-rounds: ``pipeline.online_rounds.OnlineRoundsConfig`` fields."""
    reward_checkpoint: Optional[str] = None
    """The DREM rewards: this checkpoint instead of the shipped rewards/<task>/drem.pt."""
    drem_form: Optional[str] = None
    """The DREM rewards: paper pays R, shifted R - 1 (``drem.reward.DREM_FORMS``).

    None: shifted when episodes end at success (a positive reward would pay for not finishing), else paper."""

    @classmethod
    def from_preset(cls, name: str, **overrides) -> "RLConfig":
        """The ``state`` (reward studies), ``light`` or ``image`` (CPU images) or ``paper`` config, with overrides."""
        if name not in PRESETS:
            raise ValueError(f"unknown preset {name!r}; choose one of {list(PRESETS)}")
        base = dict(preset=name)
        if name == "state":
            # Reward studies: proprioception, the F/T history and the socket's pose, no image (the reward
            # may still read the cameras: DREM renders its own). Nothing derived from a reward.
            base.update(
                cameras=(), policy_ft=True, policy_state=True, policy_qvel=True, policy_privileged=True,
                steps=50_000, buffer_size=100_000, batch_size=256, learning_starts=1_000, eval_every=2_500,
                **LEARNABLE,
                shared_encoder=False,  # no camera to share: SB3's own layout
                # The gradient step overlapped with the env step in a child process (2 cores), in bfloat16 where
                # the CPU computes it in hardware (emulated, it is slower than float32): within 2x of the env's own
                # stepping, learning at the same steps (docs/rl.md, "Speed").
                train_bf16=native_bf16(), overlap_env=True,
            )
        elif name == "light":
            # Images on this CPU: the state preset's learnability settings, the env overlapped with the gradient
            # step (fewer updates would be as fast, at a cost to learning).
            base.update(**LEARNABLE, overlap_env=True)
        elif name == "image":
            # The paper's inputs on this CPU: both cameras (32 px) and proprioception for every reward, the F/T
            # history for DREM's policy only (Section IV-D), never the socket's pose; light's learning settings.
            base.update(**LEARNABLE, overlap_env=True, policy_ft=None, steps=50_000, eval_every=2_500)
        elif name == "paper":
            # The paper: images of both cameras for every policy, F/T too for DREM's (Section IV-D);
            # a policy CNN like the reward encoder's (6 stride-2 layers at 128 px); 150k steps.
            base.update(
                image_size=128, policy_ft=None, policy_state=False, cnn_channels=(16, 32, 32, 64, 64, 64),
                steps=150_000, buffer_size=50_000, batch_size=256, learning_starts=5_000, eval_every=5_000,
            )
        unknown = set(overrides) - {f.name for f in dataclasses.fields(cls)}
        if unknown:
            raise TypeError(f"unknown RLConfig fields {sorted(unknown)}")
        return cls(**{**base, **overrides})

    def __post_init__(self):
        self.train_bf16 = bool(self.train_bf16)
        self.overlap_env = bool(self.overlap_env)
        for key in ("cameras", "cnn_channels", "net_arch", "obs_norm"):
            setattr(self, key, tuple(getattr(self, key)))
        if set(self.obs_norm) - {"state", "ft"}:
            raise ValueError(f"obs_norm takes 'state' and 'ft', got {list(self.obs_norm)}")
        from drem_maniskill.drem.reward import check_form

        if self.drem_form is not None:
            check_form(self.drem_form)
        if self.shared_encoder and self.share_features_extractor:
            raise ValueError("shared_encoder (the critic trains the extractor, on by default) and "
                             "share_features_extractor (SB3's: the actor trains it) are two ways to share it; "
                             "pick one, e.g. shared_encoder=False")
        check_fraction("action_scale", self.action_scale, "the controller's range")
        if 128 % self.image_size:
            raise ValueError(f"image_size must divide the 128 px render (8, 16, 32, 64, 128), got {self.image_size}")

    @property
    def uses_images(self) -> bool:
        """Whether the policy sees any camera (if not, the env runs in ``state_dict`` obs mode, rendering nothing)."""
        return len(self.cameras) > 0

    @property
    def uses_ft(self) -> bool:
        """Whether the policy gets the F/T history (``policy_ft=None``: only for the drem reward, as the paper).

        Never on ManiSkill's own tasks: they have no F/T sensor.
        """
        if not is_insertion_task(self.task):
            return False
        return self.reward == "drem" if self.policy_ft is None else bool(self.policy_ft)

    @property
    def overlap_env_used(self) -> bool:
        """Whether the run's env steps in a child process (``overlap_env_used`` below)."""
        return overlap_env_used(self.overlap_env, self.reward, self.algo)

    @property
    def drem_form_used(self) -> str:
        """The DREM form the run pays (``drem_form``, or by ``terminate_on_success`` when it is None)."""
        return drem_form_used(self.drem_form, self.terminate_on_success)

    @property
    def normalized_inputs(self) -> tuple:
        """The policy inputs of ``obs_norm`` that the policy actually gets."""
        present = {"state": self.policy_state, "ft": self.uses_ft}
        return tuple(k for k in self.obs_norm if present[k])

    @property
    def run_dir(self) -> Path:
        """The run directory."""
        return Path(self.out) if self.out else Path("outputs/rl") / self.task / self.reward / f"seed{self.seed}"

    def to_dict(self) -> dict:
        """JSON-serialisable form."""
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict) -> "RLConfig":
        """Inverse of ``to_dict``: every field, no other key (a stale config is refused, not half-read)."""
        names = [f.name for f in dataclasses.fields(cls)]
        missing, unknown = [k for k in names if k not in d], sorted(set(d) - set(names))
        if missing or unknown:
            found = [f"it lacks {missing}"] * bool(missing) + [f"it has unknown keys {unknown}"] * bool(unknown)
            raise ValueError(f"not an RLConfig of this version: {' and '.join(found)}; a run's config.json holds "
                             f"every field of RLConfig.to_dict(), no other")
        return cls(**d)

    def save(self, path) -> None:
        """Write the config as JSON."""
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def load(cls, path) -> "RLConfig":
        """Read a config written by ``save``."""
        return cls.from_dict(json.loads(Path(path).read_text()))


def drem_form_used(drem_form: Optional[str], terminate_on_success: bool) -> str:
    """``drem_form``, or where it is unset ``"shifted"`` if episodes end at success (the paper's R would
    then pay for not finishing), else ``"paper"``; also for config dicts that are not whole RLConfigs."""
    if drem_form is not None:
        return drem_form
    return "shifted" if terminate_on_success else "paper"


def overlap_env_used(overlap_env: bool, reward: str, algo: str = "sac") -> bool:
    """``overlap_env``, unless the reward learns from the run in this process (VICE-RAQ) or the algorithm cannot
    defer its gradient step (its class has no ``train_while_env_steps``, as ``rl.sac.SAC`` has); also for config
    dicts. An unknown reward or algorithm: False."""
    if not overlap_env:
        return False
    from drem_maniskill.rl.algos import ALGOS
    from drem_maniskill.rl.rewards import REWARDS

    if reward not in REWARDS or algo not in ALGOS:
        return False
    return REWARDS[reward].learner is None and hasattr(ALGOS[algo].cls, "train_while_env_steps")
