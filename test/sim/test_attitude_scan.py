"""The attitude's running product does not depend on how a run is cut into calls.

The node graph's simulator advances in chunks set by when commands arrive; two runs of one seed must
give the same bits (they differed by up to 1.5e-14 in the star-tracker quaternions before the scan's
association was tied to the step index).
"""

from __future__ import annotations

import numpy as np
import pytest

from taiji2_model.config import load_config
from taiji2_model.frames import quat_multiply
from taiji2_sim_pkg.core.attitude_scan import EPOCH_STEPS, AttitudeScan
from taiji2_sim_pkg.core.simulator import Simulator, maneuver_torque_commands


def _rotations(n: int, seed: int = 3) -> np.ndarray:
    q = np.random.default_rng(seed).standard_normal((n, 4)) * [1e-3, 1e-3, 1e-3, 0.0] + [0, 0, 0, 1]
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _in_chunks(initial, rotations, sizes):
    scan, parts, start = AttitudeScan(initial), [], 0
    for size in sizes:
        parts.append(scan.extend(rotations[start:start + size]))
        start += size
    assert start == rotations.shape[0]
    return np.concatenate(parts), scan


@pytest.mark.parametrize("count", [1, 15, 16, 17, EPOCH_STEPS - 1, EPOCH_STEPS, EPOCH_STEPS + 1, 3 * EPOCH_STEPS + 37])
def test_any_cutting_gives_the_same_bits(count):
    """One call (vectorised from the epoch boundary), step by step (plain floats) and random chunks."""
    rotations = _rotations(count)
    initial = np.array([0.1, -0.2, 0.3, 0.9]) / np.linalg.norm([0.1, -0.2, 0.3, 0.9])
    whole, scan = _in_chunks(initial, rotations, [count])
    steps, _ = _in_chunks(initial, rotations, [1] * count)
    sizes, left, rng = [], count, np.random.default_rng(count)
    while left:
        sizes.append(min(left, int(rng.integers(1, 2 * EPOCH_STEPS))))
        left -= sizes[-1]
    chunks, _ = _in_chunks(initial, rotations, sizes)
    np.testing.assert_array_equal(steps, whole)
    np.testing.assert_array_equal(chunks, whole)
    np.testing.assert_array_equal(scan.attitude_xyzw, whole[-1])
    # and the product itself: left to right within 8 eps per product of the chain
    expected, current = np.empty((count, 4)), initial
    for k in range(count):
        current = quat_multiply(current, rotations[k])
        expected[k] = current
    np.testing.assert_allclose(whole, expected, rtol=0, atol=8 * np.finfo(np.float64).eps * count)


def test_bad_input_is_named():
    with pytest.raises(ValueError, match="initial_xyzw"):
        AttitudeScan([0.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="rotations_xyzw: wrong shape"):
        AttitudeScan([0.0, 0.0, 0.0, 1.0]).extend(np.zeros((3, 3)))


def test_simulator_in_any_chunks_is_bitwise_one_batch():
    """Every output of the streaming simulator, advanced in uneven chunks, equals one batch call."""
    cfg = load_config("type1", overrides={"maneuver.duration_s": 200.0})
    commands = maneuver_torque_commands(cfg)
    whole = Simulator(cfg, seed=5).advance(commands)
    sim, parts, start, rng = Simulator(cfg, seed=5), [], 0, np.random.default_rng(7)
    while start < len(commands):
        size = min(int(rng.integers(1, 400)), len(commands) - start)
        parts.append(sim.advance(commands[start:start + size]))
        start += size
    np.testing.assert_array_equal(np.concatenate([p.st_quat_xyzw for p in parts]), whole.st_quat_xyzw)
    np.testing.assert_array_equal(np.concatenate([p.truth.quat_xyzw for p in parts]), whole.truth.quat_xyzw)
    np.testing.assert_array_equal(np.concatenate([p.voltages_v for p in parts]), whole.voltages_v)
    np.testing.assert_array_equal(sim.quat_xyzw, whole.truth.quat_xyzw[-1])
