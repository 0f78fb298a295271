"""drem-maniskill: DREM (Dense Rewards for Multimodal Observations) for ManiSkill 3.

Importing the package registers the tasks ``PegInHole-v1`` and ``USBInsertion-v1`` (and their
DREM-by-default aliases ``PegInHole-DREM-v1``, ``USBInsertion-DREM-v1``) in
ManiSkill's registry and in gymnasium's, so ``gym.make("PegInHole-v1")`` works after
``import drem_maniskill`` and ``gym.make("drem_maniskill:PegInHole-v1")`` works without it.
"""

__version__ = "0.1.0"

from drem_maniskill import _compat  # noqa: F401  (before any env is made)
from drem_maniskill import envs  # noqa: F401,E402  (registers the tasks)
from drem_maniskill.envs.aliases import register_drem_env  # noqa: F401,E402
