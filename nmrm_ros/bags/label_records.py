"""Label and comparison records: who gave which return to which episode, or said which of two
episodes was better, and when — the provenance a dataset built from bags keeps
(`TrajectoryDataset.meta["labels"]` / `["comparisons"]`) and the rows of a labels file
(`labelling.label_files`)."""

from __future__ import annotations


def label_record(task: str, source: str, episode: int, length: int, value: float, labeller: str,
                 stamp_ns: int) -> dict:
    """One label as provenance and export record it: who gave which return to which episode, when."""
    return {"task": task, "source": source, "episode": int(episode), "length": int(length),
            "return": None if value != value else float(value), "labeller": labeller, "stamp_ns": int(stamp_ns)}


def comparison_record(task: str, source: str, a: int, length_a: int, b: int, length_b: int, p: float,
                      labeller: str, stamp_ns: int) -> dict:
    """One comparison as a record: who said which of episodes a and b was better (p = P(a
    better): 1, 0 or 0.5), when."""
    return {"task": task, "source": source, "a": int(a), "length_a": int(length_a), "b": int(b),
            "length_b": int(length_b), "p": float(p), "labeller": labeller, "stamp_ns": int(stamp_ns)}
