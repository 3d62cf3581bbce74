"""RL on non-Markovian rewards (paper Sec. 3.3, 4.2, App. E): gymnasium wrappers that serve a MIL
model's or an oracle's reward and hidden state, double DQN and SAC from stable-baselines3, training
and oracle evaluation. Plain Python, no rclpy (the ROS bridge is `nmrm_ros.ros.topic_env`)."""

from .config import algorithm_name, load_rl_config, make_algorithm
from .double_dqn import DoubleDQN, double_q_target
from .evaluation import EvaluationResult, evaluate_agent, load_agent
from .sac import SplitLRSAC
from .training import AgentRun, EpisodeCurveCallback, LearningCurve, save_agent, train_agent
from .wrappers import (REWARD_KINDS, EpisodeSeeds, NonMarkovianRewardWrapper, OracleRewardWrapper,
                       RewardModelWrapper, make_reward_env)

__all__ = ["AgentRun", "DoubleDQN", "EpisodeCurveCallback", "EpisodeSeeds", "EvaluationResult",
           "LearningCurve", "NonMarkovianRewardWrapper", "OracleRewardWrapper", "REWARD_KINDS",
           "RewardModelWrapper", "SplitLRSAC", "algorithm_name", "double_q_target", "evaluate_agent",
           "load_agent", "load_rl_config", "make_algorithm", "make_reward_env", "save_agent",
           "train_agent"]
