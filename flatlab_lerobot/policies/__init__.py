"""LeRobot policy types shipped with FlatLab (registered on import of :mod:`flatlab_lerobot.lerobot_plugin`)."""

from lerobot.configs import NormalizationMode


def identity_normalization() -> dict[str, NormalizationMode]:
    """``normalization_mapping`` of policies that normalize inside the model (or need raw values):
    lerobot's processors pass every feature type through unchanged."""
    return {t: NormalizationMode.IDENTITY for t in ("VISUAL", "STATE", "ENV", "ACTION")}
