"""Train the DREM progress model on a task progress tree (Section III-B.3 of the paper).

Every iteration draws the same number of temporally neighbouring pairs (depths at most
``eps`` apart) and non-neighbouring pairs from the tree, embeds both states of each pair and
the goal state, and minimises ``L_triplet + alpha * L_reconstruction``. A state's temporal
position is minus its depth: the goal (depth 0) is last.

The loop checkpoints itself (model, optimiser, step, RNG) atomically every ``save_every``
iterations and resumes from that file; losses go to TensorBoard in ``<out>/tb``. The result is
a reward checkpoint (``drem_maniskill.drem.checkpoint``) with ``h(s_0)`` and ``h(s_G)`` of the
expert's first and last observations.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Callable, Optional, Sequence

import numpy as np
import torch

from drem_maniskill.drem.checkpoint import save_checkpoint
from drem_maniskill.drem.model import DREMModel, ModelConfig, check_normaliser, cosine_distance
from drem_maniskill.pipeline.dataset import TreeDataset
from drem_maniskill.pipeline.losses import reconstruction_loss, triplet_loss
from drem_maniskill.utils.atomic import atomic_path, write_text
from drem_maniskill.utils.progress import progress_bar
from drem_maniskill.version import __version__


@dataclass
class TrainConfig:
    """Training hyper-parameters; defaults are the paper's."""

    iterations: int = 20_000
    """Optimiser steps."""
    lr: float = 2e-4
    """Adam's learning rate."""
    eps: float = 4.0
    """Pairs at most this many depths apart are temporal neighbours (the triplet loss's epsilon)."""
    beta1: float = 0.04
    """Margin of the triplet loss for non-neighbouring pairs, per step of time between them: the later state must be
    closer to the goal by at least ``beta1 * (t2 - t1)``."""
    beta2: float = 0.04
    """Bound of the triplet loss for neighbouring pairs: the later state may be closer to the goal by at most this."""
    alpha: float = 0.2
    """Weight of the reconstruction loss beside the triplet loss."""
    travel_labels: float = 0.0
    """When > 0, the triplet loss reads each tree node's travel label rather than its depth (beyond the paper): a child
    is its seed's depth plus this many labels per demo median step its random action moved the hand
    (``dataset.travel_labels``). 0: the paper's depths."""
    pairs_per_batch: int = 32
    """Pairs per iteration, half temporally neighbouring and half not."""
    seed: int = 0
    """Seed of the model's init and of the pair sampler."""
    save_every: int = 200
    """Iterations between the resumable training-state files."""
    log_every: int = 20
    """Iterations between TensorBoard points."""
    threads: Optional[int] = None
    """Torch CPU threads (None: torch's default)."""
    device: str = "auto"
    """``auto``: CUDA when available, else the CPU."""
    model: ModelConfig = field(default_factory=ModelConfig)
    """The encoder-decoder's architecture."""

    @classmethod
    def preset(cls, name: str, **overrides) -> "TrainConfig":
        """``paper`` (20k iterations, 128 px) or the CPU-sized ``quick`` and ``tiny``."""
        presets = {
            "paper": {},
            "quick": dict(iterations=300, pairs_per_batch=16, model=ModelConfig(image_size=64)),
            "tiny": dict(iterations=20, pairs_per_batch=4, save_every=10, model=ModelConfig(image_size=64)),
        }
        if name not in presets:
            raise ValueError(f"unknown training preset {name!r}; choose one of {list(presets)}")
        merged = {**presets[name], **overrides}
        return cls(**merged)


def train_reward(dataset_path: str, out_dir: str, config: TrainConfig = TrainConfig(), progress: bool = True,
                 negatives: Sequence[str] = (), init_checkpoint: Optional[str] = None,
                 extra_header: Optional[dict] = None, trees: Sequence[str] = ()) -> str:
    """Train on a progress tree; writes ``<out_dir>/drem.pt`` (and resumes from ``train_state.pt``).

    ``trees``: more progress trees (other episodes of the same demo file) trained on beside the first, toward its goal;
    ``negatives``: hard-negative files added to the tree's nodes (``pipeline.policy_rounds``);
    ``init_checkpoint``: a reward checkpoint whose weights the model starts from (fine-tuning);
    ``extra_header``: entries added to the checkpoint's header.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if config.threads:
        torch.set_num_threads(config.threads)
    data = TreeDataset(dataset_path, config.model, travel=config.travel_labels)
    data.add_trees(trees, config.model)
    negative_nodes = data.add_negatives(negatives, config.model)
    if data.poses is not None:  # the scene-poses vector's length is the env's, read from its tree
        actors = _actor_count(data.header) if config.model.poses_relative else 0
        config = replace(config, model=replace(config.model, poses_size=int(data.poses.shape[1]), poses_actors=actors))
    torch.manual_seed(config.seed)
    model = _build_model(config, data, init_checkpoint)
    opt = torch.optim.Adam(model.parameters(), lr=config.lr)
    gen = torch.Generator().manual_seed(config.seed)
    state_path = out / "train_state.pt"
    config_json = json.loads(json.dumps(asdict(config)))
    step = _resume(state_path, model, opt, gen, config_json, dataset_path, len(data.depth))
    record = dict(train=config_json, dataset=str(dataset_path), trees=[str(t) for t in trees], sampler=data.header)
    write_text(out / "config.json", json.dumps(record, indent=2))

    def save(at: int) -> None:
        _save_train_state(state_path, model, opt, gen, at, config_json, dataset_path, len(data.depth))

    _optimise(model, opt, gen, data, config, step, out / "tb", save, progress)
    forest = dict(trees=forest_record(dataset_path, trees)) if trees else {}
    if negatives:
        forest["negatives"] = dict(files=[Path(n).name for n in negatives], nodes=negative_nodes)
    return export_reward(model, data, config, out / "drem.pt", {**forest, **(extra_header or {})})


def train_config_of(header: dict) -> TrainConfig:
    """The ``TrainConfig`` a checkpoint's header records (``export_reward``)."""
    known = {f for f in TrainConfig.__dataclass_fields__ if f != "model"}
    return TrainConfig(**{k: v for k, v in header["train"].items() if k in known},
                       model=ModelConfig.from_dict(header["model"]))


def fine_tune(data: TreeDataset, checkpoint: str, config: TrainConfig, path: Path,
              extra_header: Optional[dict] = None) -> str:
    """``config.iterations`` steps from ``checkpoint``'s weights on ``data``, loaded once by the caller (its negatives
    added); writes the reward to ``path``. Not resumable: an interrupted fine-tuning is redone from ``checkpoint``."""
    torch.manual_seed(config.seed)
    model = _build_model(config, data, checkpoint)
    opt = torch.optim.Adam(model.parameters(), lr=config.lr)
    gen = torch.Generator().manual_seed(config.seed)
    _optimise(model, opt, gen, data, config, 0, Path(path).parent / "tb", lambda at: None, progress=False)
    return export_reward(model, data, config, Path(path), extra_header)


def _build_model(config: TrainConfig, data: TreeDataset, init_checkpoint: Optional[str]) -> DREMModel:
    """The model to train, on ``config.device``: the scene-poses statistics of ``data``, the weights of
    ``init_checkpoint`` when given."""
    device = torch.device("cuda" if config.device == "auto" and torch.cuda.is_available() else
                          ("cpu" if config.device == "auto" else config.device))
    model = DREMModel(config.model).to(device)
    if data.poses is not None:
        model.set_poses_stats(data.poses.to(device))
    if init_checkpoint is not None:
        _load_weights(model, init_checkpoint, config.model)
    model.image_decoders.to(memory_format=torch.channels_last)
    model.image_encoders.to(memory_format=torch.channels_last)
    return model


def _losses(model: DREMModel, data: TreeDataset, goal: dict, config: TrainConfig, gen: torch.Generator):
    """One iteration's pairs through the model: ``(total, triplet, reconstruction)`` losses and the samples it read."""
    device = next(model.parameters()).device
    a, b = data.sample_pairs(config.pairs_per_batch, config.eps, gen)
    idx = torch.cat([a, b])
    batch = {k: torch.cat([v, goal[k]]).to(device) for k, v in data.batch(idx).items()}
    h, recon, inputs = model(batch)
    h_goal, h = h[-1:], h[:-1]
    dist = cosine_distance(h, h_goal)
    n = len(a)
    # Temporal position = -label (the depth unless travel labels): the goal (0) comes last.
    ta, tb = -data.label[a].to(device), -data.label[b].to(device)
    l_triplet = triplet_loss(dist[:n], dist[n:], ta, tb, config.eps, config.beta1, config.beta2).mean()
    l_recon = reconstruction_loss(recon, inputs)
    return (l_triplet + config.alpha * l_recon, l_triplet, l_recon), len(idx) + 1


def _optimise(model: DREMModel, opt, gen: torch.Generator, data: TreeDataset, config: TrainConfig, step: int,
              tb_dir: Path, save: Callable[[int], None], progress: bool) -> None:
    """Train from ``step`` to ``config.iterations``: losses to TensorBoard in ``tb_dir``, ``save(step)`` every
    ``save_every`` iterations and at the end."""
    from torch.utils.tensorboard import SummaryWriter

    writer = SummaryWriter(str(tb_dir))
    goal = data.batch(torch.tensor([data.goal_index]))
    t0, seen = time.time(), 0
    bar = progress_bar(total=config.iterations, initial=step, desc="train reward", unit="it", enabled=progress)
    model.train()
    while step < config.iterations:
        (loss, l_triplet, l_recon), samples = _losses(model, data, goal, config, gen)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        step += 1
        seen += samples
        bar.update(1)
        if step % config.log_every == 0 or step == config.iterations:
            rate = seen / max(time.time() - t0, 1e-9)
            writer.add_scalar("loss/total", loss.item(), step)
            writer.add_scalar("loss/triplet", l_triplet.item(), step)
            writer.add_scalar("loss/reconstruction", l_recon.item(), step)
            writer.add_scalar("speed/samples_per_s", rate, step)
            bar.set_postfix(triplet=f"{l_triplet.item():.4f}", recon=f"{l_recon.item():.4f}", samples_s=f"{rate:.0f}")
        if step % config.save_every == 0 or step == config.iterations:
            save(step)
    bar.close()
    writer.close()


def forest_record(first: str, trees: Sequence[str]) -> list:
    """Each tree a reward was trained on: its demo episode's seed and its node count (the header's ``trees``)."""
    from drem_maniskill.pipeline.tree import tree_file

    record = []
    for path in (first, *trees):
        with tree_file.open_tree(path) as f:
            record.append(dict(episode_seed=tree_file.read_header(f).get("episode_seed"), nodes=len(f["depth"])))
    return record


def _actor_count(header: dict) -> int:
    """How many actors the tree's env holds (the head of its scene-poses vector), read from a fresh env's state."""
    import gymnasium as gym

    env = gym.make(header["env_id"], **{**header.get("env_kwargs", {}), "obs_mode": "state_dict"})
    try:
        env.reset(seed=0)
        return len(env.unwrapped.get_state_dict().get("actors", {}))
    finally:
        env.close()


def _load_weights(model: DREMModel, path: str, config) -> None:
    """Start ``model`` from a reward checkpoint's weights; its architecture must be the one being trained."""
    from drem_maniskill.drem.checkpoint import CheckpointError, load_checkpoint

    header, weights = load_checkpoint(path)
    if ModelConfig.from_dict(header["model"]).to_dict() != config.to_dict():
        raise CheckpointError(f"{path} holds another model ({header['model']}) than the one trained "
                              f"({config.to_dict()}); start from a checkpoint of the same architecture")
    model.load_state_dict({k[len("model."):]: v for k, v in weights.items() if k.startswith("model.")})


def tree_order(model: DREMModel, data: TreeDataset, nodes: int = 512, seed: int = 0) -> float:
    """Spearman correlation between depth and latent distance to the goal over (up to ``nodes``) tree nodes.

    The training objective in one number: near 1 when the latent orders the tree as the triplet loss asks. A collapsed
    encoder can reach a small loss with every latent pointing the same way; this stays far from 1 then.
    """
    from scipy.stats import spearmanr

    model.eval()
    device = next(model.parameters()).device
    count = data.tree_nodes  # the tree's own nodes: hard negatives added after them have no place in its order
    idx = torch.randperm(count, generator=torch.Generator().manual_seed(seed))[:nodes]
    with torch.no_grad():
        def embed(rows):
            return model.encode(model.prepare({k: v.to(device) for k, v in data.batch(rows).items()}))

        goal = embed(torch.tensor([data.goal_index]))
        h = torch.cat([embed(part) for part in idx.split(128)])
    dist = cosine_distance(h, goal).cpu().numpy()
    depth = data.depth[idx].numpy()
    if np.ptp(depth) == 0 or np.ptp(dist) == 0:
        return 0.0
    return float(spearmanr(depth, dist).correlation)


def export_reward(model: DREMModel, data: TreeDataset, config: TrainConfig, path: Path,
                  extra_header: Optional[dict] = None) -> str:
    """Write the reward checkpoint: weights, ``h(s_0)``, ``h(s_G)`` and the header (plus ``extra_header``)."""
    model.eval()
    with torch.no_grad():
        device = next(model.parameters()).device
        h0 = model.encode(model.prepare({k: v.to(device) for k, v in data.expert["first"].items()}))
        hg = model.encode(model.prepare({k: v.to(device) for k, v in data.expert["last"].items()}))
    # Refused here rather than at use: a degenerate reward pays thousands and a policy run on it learns nothing.
    normaliser = check_normaliser(h0[0].cpu(), hg[0].cpu(), f"The reward trained into {path.parent}")
    header = dict(
        env_id=data.header["env_id"],
        env_kwargs=data.header.get("env_kwargs", {}),
        modalities=list(config.model.modalities),
        camera_uids=[data.camera_map[c] for c in config.model.cameras],
        image_size=config.model.image_size,
        ft_history=config.model.ft_history,
        render_style=data.header.get("env_kwargs", {}).get("render_style", "lean"),
        model=config.model.to_dict(),
        train={k: v for k, v in asdict(config).items() if k != "model"},
        sampler=data.header.get("config", {}),
        fit=dict(tree_order=tree_order(model, data), normaliser=normaliser),
        package_version=__version__,
        **(extra_header or {}),
    )
    weights = {f"model.{k}": v.contiguous() for k, v in model.state_dict().items()}
    weights["h_start"] = h0[0]
    weights["h_goal"] = hg[0]
    return save_checkpoint(str(path), header, weights)


def with_defaults(saved: dict) -> dict:
    """A saved ``TrainConfig``'s JSON (a training state's, a checkpoint header's ``train``) with every setting it
    predates at its default: what it trained with."""
    return {**json.loads(json.dumps(asdict(TrainConfig()))), **saved}


def _resumable(config_json: dict) -> dict:
    """The config keys that must match to resume (more iterations or other logging are fine)."""
    free = ("iterations", "save_every", "log_every", "threads", "device")
    return {k: v for k, v in config_json.items() if k not in free}


def _resume(state_path: Path, model, opt, gen, config_json: dict, dataset_path: str, nodes: int) -> int:
    """Load the saved training state into ``model``, ``opt`` and ``gen`` when it fits; returns the step to resume at."""
    if not state_path.exists():
        return 0
    state = torch.load(state_path, map_location="cpu", weights_only=True)
    # The same file with other contents (a re-sampled tree) starts over rather than training on a mix.
    same_data = state["dataset"] == str(Path(dataset_path).resolve()) and state.get("nodes", nodes) == nodes
    if _resumable(with_defaults(json.loads(state["config"]))) != _resumable(config_json) or not same_data:
        return 0
    model.load_state_dict(state["model"])
    opt.load_state_dict(_unflatten_opt(state["opt"]))
    gen.set_state(state["gen"])
    return int(state["step"])


def _flatten_opt(state: dict) -> dict:
    return {"state": {str(k): v for k, v in state["state"].items()}, "param_groups": json.dumps(state["param_groups"])}


def _unflatten_opt(state: dict) -> dict:
    return {"state": {int(k): v for k, v in state["state"].items()}, "param_groups": json.loads(state["param_groups"])}


def _save_train_state(path: Path, model, opt, gen, step, config_json, dataset_path, nodes: int) -> None:
    with atomic_path(path) as tmp:
        torch.save(dict(model=model.state_dict(), opt=_flatten_opt(opt.state_dict()), gen=gen.get_state(), step=step,
                        config=json.dumps(config_json), dataset=str(Path(dataset_path).resolve()), nodes=nodes), tmp)
