"""Seeing what a reward model learnt (paper Sec. 5.3, Figures 5 and 6): hidden-state embeddings,
reward maps, probe trajectories and per-episode views, written as PNGs and an index.html.

Plain Python (NumPy, torch, matplotlib); `nmrm explain` is the command-line entry point.
"""

from .probes import PROBES, Probe, probe_states
from .report import explain
from .traces import model_traces, oracle_traces

__all__ = ["PROBES", "Probe", "explain", "model_traces", "oracle_traces", "probe_states"]
