"""The kinds of feedback a reward model learns from, named once for the trainer, the labellers,
the nodes' parameters and the command line.

    returns      one return label per episode (a person's or an oracle's number)
    preferences  comparisons of two episodes (which earned more), no returns
    both         the two together

How each is trained on: `nmrm_ros.mil.training` (one loss per kind); adding a kind:
docs/development.md, "Adding a feedback kind".
"""

from __future__ import annotations

FEEDBACK = ("returns", "preferences", "both")


def unknown_feedback(value: str, name: str = "feedback") -> str | None:
    """None if `value` is a kind of feedback, else the one-line error for parameter or option `name`."""
    if value in FEEDBACK:
        return None
    return f"{name} must be {', '.join(FEEDBACK[:-1])} or {FEEDBACK[-1]}, got {value!r}"
