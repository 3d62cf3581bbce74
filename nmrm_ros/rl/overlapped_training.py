"""Gradient steps that overlap the environment's step: for an agent learning through the graph.

SB3's off-policy `learn()` alternates: act, `env.step()` (through the graph: publish the action and
wait for the next RewardStep, ~1 ms of other processes' work), store the transition, one gradient
step. With `overlap_training` on, `train()` only records its request and `train_pending()` runs it;
the graph's `TopicEnv` calls `train_pending()` right after publishing an action, so the gradient
step of step t runs while env_sim and the reward model compute s_{t+1}. The pipeline is one step
behind SB3's order: the step's batch is drawn before transition t is stored, and action a_{t+1} is
chosen before that step's gradient step. With it off (the default here), SB3's order is kept
exactly (the graph then gives the wrapper's transitions and weights bit for bit).
"""

from __future__ import annotations


class OverlappedTraining:
    """Mixin for an SB3 off-policy algorithm whose `train()` starts with
    `if self._defer_train(gradient_steps, batch_size): return`."""

    overlap_training = False
    _pending_train = None

    def _defer_train(self, gradient_steps: int, batch_size: int) -> bool:
        if not self.overlap_training:
            return False
        self._pending_train = (gradient_steps, batch_size)
        return True

    def train_pending(self) -> None:
        """Run the gradient steps `train()` was last asked for (if any)."""
        if self._pending_train is None:
            return
        gradient_steps, batch_size = self._pending_train
        self._pending_train = None
        self.overlap_training = False
        try:
            self.train(gradient_steps, batch_size)
        finally:
            self.overlap_training = True

    def _excluded_save_params(self) -> list:
        return super()._excluded_save_params() + ["_pending_train", "overlap_training"]
