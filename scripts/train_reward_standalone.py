"""``drem-maniskill train-reward`` on a machine without ManiSkill (a GPU box that has only torch and h5py).

    python3 scripts/train_reward_standalone.py --dataset TREE.h5 --out DIR [--modalities fixed wrist] \
        [--iterations 20000] [--preset quick] [--device cuda]

Training reads the progress tree and nothing else, but ``import drem_maniskill`` registers the
tasks with ManiSkill. Here the package is entered without its ``__init__`` so that only the
training modules (torch, h5py, numpy, tqdm, tensorboard) load; the checkpoint is the same file
``train-reward`` writes, with the same header and resume behaviour.
"""

from __future__ import annotations

import argparse
import sys
import types
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _enter_package_without_init() -> None:
    """Make ``drem_maniskill.<sub>`` importable without running ``drem_maniskill/__init__.py``."""
    try:
        import mani_skill  # noqa: F401

        return  # ManiSkill is here: the normal import works
    except ImportError:
        pass
    pkg = types.ModuleType("drem_maniskill")
    pkg.__path__ = [str(ROOT / "drem_maniskill")]
    sys.modules["drem_maniskill"] = pkg


def main() -> None:
    """Command line (the options of ``drem-maniskill train-reward`` that training needs)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dataset", required=True)
    parser.add_argument("--out", required=True)
    parser.add_argument("--preset", default="quick")
    parser.add_argument("--iterations", type=int)
    parser.add_argument("--modalities", nargs="+")
    parser.add_argument("--device", default="auto")
    parser.add_argument("--seed", type=int)
    args = parser.parse_args()
    _enter_package_without_init()
    from drem_maniskill.drem.model import ModelConfig
    from drem_maniskill.pipeline.dataset import dataset_modalities
    from drem_maniskill.pipeline.train_reward import TrainConfig, train_reward

    base = TrainConfig.preset(args.preset)
    modalities = tuple(args.modalities) if args.modalities else dataset_modalities(args.dataset)
    model = ModelConfig(**{**base.model.to_dict(), "modalities": modalities})
    overrides = {k: v for k, v in dict(iterations=args.iterations, seed=args.seed, device=args.device).items() if v is not None}
    config = TrainConfig(**{**{f: getattr(base, f) for f in base.__dataclass_fields__}, **overrides, "model": model})
    print(f"training config: {config}", flush=True)
    print(f"reward checkpoint: {train_reward(args.dataset, args.out, config)}")


if __name__ == "__main__":
    main()
