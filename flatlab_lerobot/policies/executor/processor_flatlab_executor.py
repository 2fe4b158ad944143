"""Pre/post processors of ``flatlab_executor``: rename -> batch -> device in, cpu out.  No lerobot
normalizer: the model centres the cloud on its mean and works in that frame (see the config)."""

from __future__ import annotations

from lerobot.processor.factory import make_default_policy_processor_steps, make_policy_processor_pipelines


def make_flatlab_executor_pre_post_processors(config, dataset_stats=None):
    # the (un)normalizer steps are identities (config.normalization_mapping), kept so the saved pipeline
    # has the steps lerobot-train overrides on --resume / --policy.path (it fails without them)
    s = make_default_policy_processor_steps(config, None)
    return make_policy_processor_pipelines(
        input_steps=[s.rename_observations, s.add_batch_dim, s.to_device, s.normalize],
        output_steps=[s.unnormalize, s.to_cpu],
    )
