"""sb3-trlsd: Transfer Reinforcement Learning with Shared Dynamics (Laroche & Barlier, AAAI 2017) for SB3.

Importing the package registers the maze, ``TRLSD/SharedDynamicsMaze-v0``.
"""

import sb3_trlsd_envs  # noqa: F401  (registers TRLSD/SharedDynamicsMaze-v0)
from sb3_trlsd.buffers import SharedDynamicsReplayBuffer
from sb3_trlsd.data import Transitions, collect_transitions
from sb3_trlsd.feature_maps import FeatureMap, RandomFourierFeatures, RBFGrid
from sb3_trlsd.policies import LinearPolicy, MlpPolicy
from sb3_trlsd.relabelling_buffer import RelabellingReplayBuffer, dqn_q_values
from sb3_trlsd.reward_heads import (
    GridCells,
    KnownRewardHead,
    RewardHead,
    RidgeRewardHead,
    TabularRewardHead,
    make_reward_head,
)
from sb3_trlsd.task_learner import TaskLearner
from sb3_trlsd.trlsd import TRLSD
from sb3_trlsd.version import __version__

__all__ = [
    "TRLSD",
    "FeatureMap",
    "GridCells",
    "KnownRewardHead",
    "LinearPolicy",
    "MlpPolicy",
    "RBFGrid",
    "RandomFourierFeatures",
    "RelabellingReplayBuffer",
    "RewardHead",
    "RidgeRewardHead",
    "SharedDynamicsReplayBuffer",
    "TabularRewardHead",
    "TaskLearner",
    "Transitions",
    "__version__",
    "collect_transitions",
    "dqn_q_values",
    "make_reward_head",
]
