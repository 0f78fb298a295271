"""The offline DREM chain: expert demo -> backward sampling -> progress tree -> training -> checkpoint -> examination.

* ``tree.backward.backward_sample``: the task progress tree (HDF5, ``tree.tree_file``) from an expert trajectory,
  configured by ``tree.config.SamplerConfig`` (both re-exported here);
* ``dataset.TreeDataset``: that tree as training data;
* ``train_reward.train_reward``: the encoder-decoder with the triplet and reconstruction losses
  (``losses``), exported as a reward checkpoint (``drem_maniskill.drem.checkpoint``);
* the examination of the checkpoint (its quality measures and the paper's Fig. 4 plot) is
  ``drem_maniskill.evaluate.examine.examine``.
"""

from drem_maniskill.pipeline.tree.backward import backward_sample
from drem_maniskill.pipeline.tree.config import SamplerConfig

__all__ = ["SamplerConfig", "backward_sample"]
