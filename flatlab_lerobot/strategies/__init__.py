"""Strategies A / B / C as sequences of primitives, and the scripted expert that poses them.

The expert only reads *privileged state* (``environment_state``: object pose, size, material,
table height and edge) plus the robot's joints, so the same code runs in-process
(``flatlab demo``) and as a LeRobot policy (``flatlab_scripted``).  Each stage is a function
``stage(expert, world, poses, grip, ctx) -> Primitive`` evaluated when the stage starts, on the
state at that moment: after the slide of strategy A, the grasp is aimed at where the book really
ended up.

* :mod:`.world`: the expert's view of the scene and what the strategies share;
* :mod:`.a_push_to_edge`, :mod:`.b_squeeze`, :mod:`.c_fold_pinch`: one module per strategy;
* :mod:`.registry`: :data:`STRATEGIES`, label -> stages, and :data:`STAGE_SPECS`, their primitive names and timing;
* :mod:`.expert`: :class:`Expert`, kinematics + IK + the episode generator.
"""

from flatlab_lerobot.strategies.expert import Expert
from flatlab_lerobot.strategies.registry import STAGE_SPECS, STRATEGIES
from flatlab_lerobot.strategies.world import StageSpec, World

__all__ = ["STAGE_SPECS", "STRATEGIES", "Expert", "StageSpec", "World"]
