"""LeRobot policy types shipped with FlatLab (registered on import of :mod:`flatlab_lerobot.lerobot_plugin`)."""
