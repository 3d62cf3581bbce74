"""Episode prefixes: a dataset where some episodes end at a random step, labelled with the return
they had earned by then.

Return labels say how much an episode earned, not when: when every episode runs to the same
length and the policy that made them is predictable, a model can pay the credit for a phase
before or after it is earned and fit every return (Lunar Lander's hover credit paid at take-off).
An episode cut at step L carries the return of its first L steps, so credit paid early is
penalised wherever a cut falls between the payment and the steps that earn it.

    short = cut_episodes(ds, fraction=0.5, seed=0)

The label of a cut episode is the oracle's per-step rewards summed up to the cut (`ds.rewards`),
so this is for oracle-labelled datasets only: one whose labels are not the oracle's returns (a
person's, or a bag without the oracle's ground truth) is refused. The screening class stays that
of the whole episode.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .trajectories import TrajectoryDataset


def cut_episodes(ds: TrajectoryDataset, fraction: float, seed: int) -> TrajectoryDataset:
    """A copy of `ds` where a random `fraction` in [0, 1] of the episodes (those longer than one
    step) end at a step drawn uniformly from 1 .. length - 1; their return is the sum of the
    oracle's rewards up to there (the others keep their labels), their final state the state after that step. Seeded by `seed`."""
    if not 0.0 <= fraction <= 1.0:
        raise ValueError(f"the fraction of episodes to cut must be in [0, 1], got {fraction}")
    fix = "use prefix_fraction 0 (nmrm train --prefix-fraction 0)"
    if ds.rewards is None or not np.isfinite(ds.rewards).all() or ds.meta.get("oracle_ground_truth") is False:
        raise ValueError(f"prefix labels need the oracle's per-step rewards of every episode, and these "
                         f"episodes have none: {fix}")
    labelled = np.flatnonzero(np.isfinite(ds.returns))
    oracle = ds.rewards[labelled].sum(axis=1)
    wrong = np.flatnonzero(~np.isclose(ds.returns[labelled], oracle, rtol=1e-5, atol=1e-6))
    if len(wrong):
        i = wrong[0]
        raise ValueError(f"prefix labels are the oracle's, and these labels are not (episode {labelled[i]}: "
                         f"label {ds.returns[labelled[i]]:g}, the oracle's return {oracle[i]:g}): {fix}")
    if ds.preferences is not None and len(ds.preferences):
        raise ValueError("cutting episodes would leave its comparisons judging episodes that changed")
    rng = np.random.default_rng(seed)
    lengths = ds.lengths.astype(np.int64).copy()
    cuttable = np.flatnonzero(lengths > 1)
    chosen = rng.choice(cuttable, size=int(round(fraction * len(cuttable))), replace=False)
    new_lengths = lengths.copy()
    new_lengths[chosen] = [rng.integers(1, lengths[i]) for i in chosen]
    live = np.arange(ds.states.shape[1])[None, :] < new_lengths[:, None]
    final_states = None
    if ds.final_states is not None:
        final_states = ds.final_states.copy()
        final_states[chosen] = ds.states[chosen, new_lengths[chosen]]

    def keep(a: np.ndarray | None) -> np.ndarray | None:
        if a is None:
            return None
        mask = live.reshape(live.shape + (1,) * (a.ndim - 2))
        return np.where(mask, a, 0).astype(a.dtype)

    rewards = keep(ds.rewards)
    returns = ds.returns.copy()
    returns[chosen] = rewards[chosen].sum(axis=1)
    return dataclasses.replace(
        ds, states=keep(ds.states), lengths=new_lengths.astype(ds.lengths.dtype), actions=keep(ds.actions),
        rewards=rewards, hidden=keep(ds.hidden), final_states=final_states, privileged=keep(ds.privileged),
        returns=returns,
        meta=dict(ds.meta, cut_fraction=float(fraction), cut_seed=int(seed), cut_episodes=int(len(chosen))))
