"""Pre/post processors of ``flatlab_dp3``: rename -> batch -> device -> normalize in, unnormalize ->
cpu out, as lerobot's diffusion policy, except that the normalizer leaves the point cloud alone
(the model crops, samples and scales it into [-1, 1] itself; lerobot's statistics of an (N, 3)
feature are per point index, meaningless for an unordered cloud)."""

from __future__ import annotations

from lerobot.processor import NormalizerProcessorStep
from lerobot.processor.factory import make_default_policy_processor_steps, make_policy_processor_pipelines


def make_flatlab_dp3_pre_post_processors(config, dataset_stats=None):
    s = make_default_policy_processor_steps(config, dataset_stats)
    feats = {k: v for k, v in {**config.input_features, **config.output_features}.items() if k != config.pointcloud_key}
    normalize = NormalizerProcessorStep(features=feats, norm_map=config.normalization_mapping, stats=dataset_stats)
    return make_policy_processor_pipelines(
        input_steps=[s.rename_observations, s.add_batch_dim, s.to_device, normalize],
        output_steps=[s.unnormalize, s.to_cpu],
    )
