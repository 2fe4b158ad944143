"""Pre/post processors of ``flatlab_unified``: rename -> batch -> device in, cpu out.  No
(un)normalization: the generator and the executor normalize their clouds themselves, and the state
machine reads raw joint angles and the raw cell calibration."""

from __future__ import annotations

from lerobot.processor.factory import make_default_policy_processor_steps, make_policy_processor_pipelines


def make_flatlab_unified_pre_post_processors(config, dataset_stats=None):
    s = make_default_policy_processor_steps(config, None)
    return make_policy_processor_pipelines(
        input_steps=[s.rename_observations, s.add_batch_dim, s.to_device],
        output_steps=[s.to_cpu],
    )
