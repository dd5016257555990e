"""The Taiji-2 nominal model that the simulator and the estimators share (numpy, scipy, PyYAML only).

- :mod:`.config` / :mod:`.config_schema`: layouts (YAML), overrides, validation, the dataclass tree
- :mod:`.frames`: CRF/TMRF rotations (the C_i matrices) and quaternion algebra
- :mod:`.grs`: the GRS readout equations and voltage conversion
- :mod:`.timing`: what a stamp means and when a command acts
- :mod:`.contract`: the raw-data contract's topics and types
- :mod:`.maneuver` / :mod:`.maneuver_families`: maneuvers, maneuver files and the shipped designs
- :mod:`.effects` / :mod:`.effect_catalog`: named unmodelled effects (switches with SI magnitudes)
- :mod:`.noise`: seeded, named noise streams
- :mod:`.package_files`: where a workspace package's ``config/`` folder is
"""
