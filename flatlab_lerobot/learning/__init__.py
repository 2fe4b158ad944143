"""The paper's two learning sets, built from the same simulation pipeline as the demonstrations.

* :mod:`.strategy_set`: object clouds (2048 points, unit sphere) with strategy labels, for the
  strategy generator (``flatlab strategy-set``),
* :mod:`.primitive_set`: the scene cloud at each primitive's start with its start/end 6-D
  gripper poses, for the action execution module (``flatlab primitive-set``).
"""

import argparse


def int_at_least(lo: int):
    """An argparse ``type``: an integer >= ``lo`` (argparse names the option in its error)."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be an integer >= {lo}, got {text!r}") from None
        if v < lo:
            raise argparse.ArgumentTypeError(f"must be an integer >= {lo}, got {text!r}")
        return v

    return parse
