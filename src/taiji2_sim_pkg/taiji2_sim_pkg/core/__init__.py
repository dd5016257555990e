"""Middleware-free numerical core of the Taiji-2 spacecraft simulator.

Imports only numpy, scipy, PyYAML and the standard library. Modules:

- :mod:`.config`: YAML layouts, overrides, validation (dataclasses in :mod:`.config_schema`)
- :mod:`.frames`: CRF/TMRF rotations and quaternion algebra
- :mod:`.maneuver`: square-wave torque maneuver and thrust check
- :mod:`.noise`: seeded, named noise streams
- :mod:`.dynamics`: rigid-body attitude propagation (streaming and batch)
- :mod:`.grs`: GRS readout model and voltage conversion
- :mod:`.star_tracker`: star-tracker measurement model
- :mod:`.effects`: extension points for injected effects
- :mod:`.simulator`: the simulator (streaming ``step`` and ``simulate_batch``)
- :mod:`.range_check`: GRS range monitoring and peak reports
"""
