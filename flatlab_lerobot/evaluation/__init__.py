"""The evaluation protocol (``flatlab eval``: a policy over splits x objects x trials, strategy choice S and
grasp success G, each episode exactly as ``lerobot-eval`` runs it; :mod:`.protocol`) and the asset-library
validation built on it (``flatlab assets report``: every object under every strategy, grounded labels;
:mod:`.asset_validation`)."""
