"""The strategy registry: strategy label -> its sequence of stages (one module per strategy)."""

from __future__ import annotations

from flatlab_lerobot.strategies import a_push_to_edge, b_squeeze, c_fold_pinch

STRATEGIES = {
    "A": a_push_to_edge.STAGES,
    "B": b_squeeze.STAGES,
    "C": c_fold_pinch.STAGES,
}
"""Each strategy as its sequence of stages (each stage poses one primitive)."""

STAGE_SPECS = {
    "A": a_push_to_edge.SPECS,
    "B": b_squeeze.SPECS,
    "C": c_fold_pinch.SPECS,
}
"""Each strategy's stage specs (:class:`~flatlab_lerobot.strategies.world.StageSpec`: primitive name,
duration, transit), aligned with :data:`STRATEGIES`."""
