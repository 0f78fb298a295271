"""The offline DREM chain: expert demo -> backward sampling -> progress tree -> training -> checkpoint -> examination.

* ``sampling.backward_sample``: the task progress tree (HDF5) from an expert trajectory;
* ``dataset.TreeDataset``: that tree as training data;
* ``train_reward.train_reward``: the encoder-decoder with the triplet and reconstruction losses
  (``losses``), exported as a reward checkpoint (``drem_maniskill.drem.checkpoint``);
* ``examine.examine``: the checkpoint's quality measures and the paper's Fig. 4 plot.
"""
