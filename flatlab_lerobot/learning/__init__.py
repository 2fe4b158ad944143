"""The paper's two learning sets, built from the same simulation pipeline as the demonstrations.

* :mod:`.strategy_set`: object clouds (2048 points, unit sphere) with strategy labels, for the
  strategy generator (``flatlab strategy-set``),
* :mod:`.primitive_set`: the scene cloud at each primitive's start with its start/end 6-D
  gripper poses, for the action execution module (``flatlab primitive-set``).
"""
