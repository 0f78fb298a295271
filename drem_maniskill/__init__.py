"""drem-maniskill: DREM (Dense Rewards for Multimodal Observations) for ManiSkill 3.

Importing the package registers the tasks of ``drem_maniskill.envs.TASKS`` (``PegInHole-v1``,
``USBInsertion-v1``) and their DREM-by-default aliases (``PegInHole-DREM-v1``,
``USBInsertion-DREM-v1``) in ManiSkill's registry and in gymnasium's, so
``gym.make("PegInHole-v1")`` works after ``import drem_maniskill`` and
``gym.make("drem_maniskill:PegInHole-v1")`` works without it. It also registers the ``drem-rounds``
reward (``pipeline.online_rounds``) in ``rl.rewards.REWARDS``. The layers and the data's journey
through them are in docs/architecture.md.
"""

from drem_maniskill.utils import compat as _compat  # noqa: F401  (before any env is made)
from drem_maniskill.version import __version__  # noqa: F401,E402
from drem_maniskill import envs  # noqa: F401,E402  (registers the tasks)
from drem_maniskill.envs import TASKS, register_drem_env  # noqa: F401,E402
from drem_maniskill.pipeline import online_rounds as _online_rounds  # noqa: F401,E402  (registers drem-rounds)
