"""Square-wave maneuver: waveform, edges, validation, thrust check against the 0.1-100 uN thrusters."""

import numpy as np
import pytest

from taiji2_model.config import ConfigError, load_config
from taiji2_model.maneuver import ManeuverError, SquareWaveManeuver, thrust_per_thruster_n

AMPLITUDE = np.array([3e-6, 3e-6, 13e-6])
PHASE = np.array([0.0, 62.5, 31.25])


def make(**changes):
    params = {"period_s": 250.0, "amplitude_n_m": AMPLITUDE, "phase_s": PHASE, "start_s": 100.0,
              "duration_s": 1000.0}
    params.update(changes)
    return SquareWaveManeuver(**params)


def test_waveform_signs_window_and_series():
    m = make()
    # axis k: +A during the first half period after start + phase_k, -A during the second
    for axis in range(3):
        t_edge = 100.0 + PHASE[axis]
        assert m.torque_at(t_edge + 1.0)[axis] == AMPLITUDE[axis]
        assert m.torque_at(t_edge + 124.0)[axis] == AMPLITUDE[axis]
        assert m.torque_at(t_edge + 126.0)[axis] == -AMPLITUDE[axis]
        assert m.torque_at(t_edge + 251.0)[axis] == AMPLITUDE[axis]
        assert m.torque_at(t_edge)[axis] == AMPLITUDE[axis]  # an edge belongs to the new half period
    np.testing.assert_array_equal(m.torque_at(99.9), np.zeros(3))
    np.testing.assert_array_equal(m.torque_at(1100.0), np.zeros(3))  # end is exclusive
    assert np.all(m.torque_at(1099.9) != 0.0)
    t = np.linspace(0.0, 1200.0, 2401)
    series = m.torque_series(t)
    assert series.shape == (t.size, 3)
    np.testing.assert_array_equal(series, np.array([m.torque_at(x) for x in t]))
    # zero mean over whole periods inside the window
    inside = m.torque_series(100.0 + np.arange(0, 1000.0, 0.1))
    np.testing.assert_allclose(inside.mean(axis=0), 0.0, atol=1e-20)


def test_switch_times_are_the_edges():
    m = make()
    edges = m.switch_times(0.0, 2000.0)
    assert edges[0] == 100.0 and edges[-1] == 1100.0
    assert np.all(np.diff(edges) > 0)
    for t in edges[1:-1]:
        assert not np.array_equal(m.torque_at(t - 1e-3), m.torque_at(t + 1e-3))
    samples = np.arange(0.0, 1200.0, 0.01)
    torque = m.torque_series(samples)
    changes = samples[1:][np.any(torque[1:] != torque[:-1], axis=1)]
    # every change of the sampled waveform lies within one sample after a listed edge
    assert all(np.min(np.abs(edges - c)) < 0.0100001 for c in changes)
    assert len(m.switch_times(200.0, 300.0)) == np.sum((edges >= 200.0) & (edges < 300.0))
    assert make(amplitude_n_m=0.0).switch_times(0.0, 2000.0).size == 0


@pytest.mark.parametrize(
    ("changes", "parameter"),
    [
        ({"period_s": 0.0}, "period_s"),
        ({"period_s": -250.0}, "period_s"),
        ({"period_s": float("nan")}, "period_s"),
        ({"amplitude_n_m": [1e-6, 2e-6]}, "amplitude_n_m"),
        ({"phase_s": [0.0, np.inf, 0.0]}, "phase_s"),
        ({"duration_s": -1.0}, "duration_s"),
        ({"start_s": "soon"}, "start_s"),
    ],
)
def test_invalid_parameters_are_named(changes, parameter):
    with pytest.raises(ManeuverError) as caught:
        make(**changes)
    assert caught.value.parameter == parameter
    assert str(caught.value).startswith(parameter + ":")
    assert isinstance(caught.value, ValueError) and isinstance(caught.value, ConfigError)


@pytest.mark.parametrize("layout", ["type1", "type2"])
def test_paper_maneuvers_pass_the_thrust_check(layout):
    cfg = load_config(layout)
    m = SquareWaveManeuver.from_config(cfg.maneuver)
    m.check_thrust(cfg.thrusters.min_thrust_n, cfg.thrusters.max_thrust_n, cfg.thrusters.lever_arm_m)
    thrust = thrust_per_thruster_n(m.amplitude_n_m, cfg.thrusters.lever_arm_m)
    assert np.all((thrust >= 0.1e-6) & (thrust <= 100e-6))


@pytest.mark.parametrize(
    ("amplitude", "axis"),
    [([3e-6, 3e-6, 150e-6], "Z"), ([101e-6, 3e-6, 13e-6], "X"), ([3e-6, 0.05e-6, 13e-6], "Y"),
     ([3e-6, -0.05e-6, 13e-6], "Y")],
)
def test_thrust_outside_the_thruster_range_is_refused_naming_the_axis(amplitude, axis):
    cfg = load_config("type1")
    m = make(amplitude_n_m=amplitude)
    with pytest.raises(ManeuverError) as caught:
        m.check_thrust(cfg.thrusters.min_thrust_n, cfg.thrusters.max_thrust_n, cfg.thrusters.lever_arm_m)
    assert caught.value.parameter == f"amplitude_n_m[{axis}]"


def test_zero_amplitude_axis_needs_no_thruster():
    make(amplitude_n_m=[0.0, 3e-6, 0.0]).check_thrust(1e-7, 1e-4, 1.0)
    thrust = thrust_per_thruster_n([-2e-6, 0.0, 5e-6], 2.0)
    np.testing.assert_allclose(thrust, [1e-6, 0.0, 2.5e-6], rtol=1e-15)
