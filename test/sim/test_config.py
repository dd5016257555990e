"""Configuration: nominal layouts, overrides, provenance round trip, and validation messages."""

import dataclasses
import math

import numpy as np
import pytest
import yaml

from taiji2_model.config import (
    NOISE_SOURCE_NAMES,
    ConfigError,
    SimConfig,
    builtin_layouts,
    load_config,
)


def test_builtin_layouts_exist():
    layouts = builtin_layouts()
    assert {"type1", "type2"} <= set(layouts)
    for path in layouts.values():
        assert path.is_file()
    # node parameter files live in the same directory and are not layouts
    assert not {"spacecraft_sim", "maneuver_commander"} & set(layouts)


@pytest.mark.parametrize(
    ("layout", "inertia_diag", "d1", "amplitude"),
    [
        ("type1", (1100.0, 1400.0, 2400.0), (100e-6, 0.18, 200e-6), (3e-6, 3e-6, 13e-6)),
        ("type2", (2600.0, 2600.0, 4800.0), (0.2164, 0.1251, 200e-6), (11e-6, 3e-6, 19e-6)),
    ],
)
def test_nominal_values_match_physics_md(layout, inertia_diag, d1, amplitude):
    cfg = load_config(layout)
    assert cfg.layout == layout
    assert cfg.sample_rate_hz == 10.0
    assert cfg.spacecraft.mass_kg == 1500.0
    np.testing.assert_array_equal(cfg.spacecraft.inertia_kg_m2, np.diag(inertia_diag))
    s1, s2 = cfg.grs.sensors
    assert (s1.grs_id, s2.grs_id) == (1, 2)
    np.testing.assert_allclose(s1.com_offset_m, d1, rtol=0, atol=0)
    np.testing.assert_allclose(s2.com_offset_m, (d1[0], -d1[1], d1[2]), rtol=0, atol=0)
    np.testing.assert_array_equal(s1.angular_scale_factors, (5.524e-8, 5.524e-8, 7.365e-8))
    # G_Px, G_Py, G_Pz = r (G_Ppsi, G_Pphi, G_Ptheta), r = a^2 / (6 l), a = 46 mm, l = 11.5 mm
    r = 0.046**2 / (6 * 0.0115)
    np.testing.assert_allclose(s1.linear_scale_factors, r * np.array([7.365e-8, 5.524e-8, 5.524e-8]),
                               rtol=1e-15)
    assert math.isclose(cfg.grs.linear_to_angular_ratio_m, r, rel_tol=1e-15)
    np.testing.assert_array_equal(cfg.maneuver.amplitude_n_m, amplitude)
    np.testing.assert_array_equal(cfg.maneuver.phase_s, (0.0, 250.0 / 4, 250.0 / 8))
    assert cfg.maneuver.period_s == 250.0
    assert cfg.grs.range_m_s2 == 1e-9
    assert cfg.grs.alpha_deg == 60.0
    noise = cfg.noise
    np.testing.assert_array_equal(noise.lfs_translational.asd, (2.4e-12, 3.6e-12, 3.6e-12))
    np.testing.assert_array_equal(noise.lfs_rotational.asd, (2e-11, 3.5e-11, 3.5e-11))
    np.testing.assert_array_equal(noise.tm_environment.asd, (3e-14,) * 3)
    np.testing.assert_array_equal(noise.thruster_force.asd, (1e-7,) * 3)
    np.testing.assert_array_equal(noise.thruster_torque.asd, (1e-7,) * 3)
    assert noise.grs_voltage.linear_equivalent_asd_m_s2_rthz == 2.2e-14
    srp = noise.srp
    assert (srp.asd_at_f_ref_m_s2_rthz, srp.f_ref_hz, srp.f_corner_hz) == (1.1e-11, 3e-3, 1e-5)
    np.testing.assert_allclose(noise.star_tracker.sigma_rad, np.radians(0.2 / 3600.0), rtol=1e-12)
    for name in NOISE_SOURCE_NAMES:
        assert getattr(noise, name).enabled


def test_overrides_and_round_trip():
    cfg = load_config("type2", overrides={"noise.star_tracker.enabled": False, "maneuver.duration_s": 3600.0,
                                          "grs.sensors.1.com_offset_m": [0.2, -0.1, 0.0]})
    assert cfg.noise.star_tracker.enabled is False
    assert cfg.maneuver.duration_s == 3600.0
    np.testing.assert_array_equal(cfg.grs.sensors[1].com_offset_m, (0.2, -0.1, 0.0))
    plain = cfg.to_dict()
    yaml.safe_dump(plain)  # serialisable
    again = load_config(plain)
    assert again == cfg
    assert again.to_dict() == plain


def test_yaml_file_and_exponent_strings(tmp_path):
    plain = load_config("type1").to_dict()
    plain["grs"]["range_m_s2"] = "2e-9"  # YAML 1.1 reads 2e-9 as a string; accepted as a number
    path = tmp_path / "mine.yaml"
    path.write_text(yaml.safe_dump(plain))
    cfg = load_config(str(path))
    assert cfg.grs.range_m_s2 == 2e-9


def test_config_is_immutable():
    cfg = load_config("type1")
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.sample_rate_hz = 5.0  # type: ignore[misc]
    with pytest.raises(ValueError, match="read-only"):
        cfg.spacecraft.inertia_kg_m2[0, 0] = 1.0
    assert isinstance(cfg, SimConfig)


BAD_OVERRIDES = [
    # (override key, value, parameter named in the error, words in the problem)
    ("spacecraft.inertia_kg_m2", [[1100, 5, 0], [0, 1400, 0], [0, 0, 2400]], "spacecraft.inertia_kg_m2",
     "not symmetric positive definite"),
    ("spacecraft.inertia_kg_m2", [[-1100, 0, 0], [0, 1400, 0], [0, 0, 2400]], "spacecraft.inertia_kg_m2",
     "not symmetric positive definite"),
    ("spacecraft.inertia_kg_m2", [[0, 0, 0], [0, 0, 0], [0, 0, 0]], "spacecraft.inertia_kg_m2",
     "not symmetric positive definite"),
    ("spacecraft.inertia_kg_m2", [1100, 1400, 2400], "spacecraft.inertia_kg_m2", "wrong shape"),
    ("spacecraft.inertia_kg_m2", [[100, 0, 0], [0, 100, 0], [0, 0, 2400]], "spacecraft.inertia_kg_m2",
     "triangle"),
    ("spacecraft.mass_kg", 0.0, "spacecraft.mass_kg", "> 0"),
    ("spacecraft.mass_kg", -1500.0, "spacecraft.mass_kg", "> 0"),
    ("spacecraft.mass_kg", "heavy", "spacecraft.mass_kg", "number"),
    ("spacecraft.initial_attitude_xyzw", [0, 0, 0, 2], "spacecraft.initial_attitude_xyzw", "unit"),
    ("spacecraft.initial_rate_rad_s", [0, 0], "spacecraft.initial_rate_rad_s", "wrong shape"),
    ("sample_rate_hz", 0.0, "sample_rate_hz", "> 0"),
    ("sample_rate_hz", float("nan"), "sample_rate_hz", "finite"),
    ("maneuver.period_s", 0.0, "maneuver.period_s", "> 0"),
    ("maneuver.period_s", -250.0, "maneuver.period_s", "> 0"),
    ("maneuver.duration_s", -1.0, "maneuver.duration_s", ">= 0"),
    ("maneuver.amplitude_n_m", [1e-6, 2e-6], "maneuver.amplitude_n_m", "wrong shape"),
    ("noise.lfs_translational.asd_m_s2_rthz", [-2.4e-12, 3.6e-12, 3.6e-12],
     "noise.lfs_translational.asd_m_s2_rthz", ">= 0"),
    ("noise.thruster_torque.asd_n_m_rthz", -1e-7, "noise.thruster_torque.asd_n_m_rthz", ">= 0"),
    ("noise.thruster_force.asd_n_rthz", -1e-7, "noise.thruster_force.asd_n_rthz", ">= 0"),
    ("noise.srp.asd_at_f_ref_m_s2_rthz", -1.1e-11, "noise.srp.asd_at_f_ref_m_s2_rthz", ">= 0"),
    ("noise.srp.f_corner_hz", 0.0, "noise.srp.f_corner_hz", "> 0"),
    ("noise.grs_voltage.linear_equivalent_asd_m_s2_rthz", -2.2e-14,
     "noise.grs_voltage.linear_equivalent_asd_m_s2_rthz", ">= 0"),
    ("noise.star_tracker.sigma_rad", -1e-6, "noise.star_tracker.sigma_rad", ">= 0"),
    ("noise.star_tracker.enabled", "yes", "noise.star_tracker.enabled", "true or false"),
    ("grs.range_m_s2", 0.0, "grs.range_m_s2", "> 0"),
    ("grs.sensors.0.com_offset_m", [0.1, 0.2], "grs.sensors.0.com_offset_m", "wrong shape"),
    ("grs.sensors.1.angular_scale_factors", [5.5e-8, 0.0, 7.4e-8], "grs.sensors.1.angular_scale_factors",
     "> 0"),
    ("grs.sensors.0.grs_id", 2, "grs.sensors.0.grs_id", "must be 1"),
    ("grs.sensors", [], "grs.sensors", "exactly two"),
    ("thrusters.max_thrust_n", 1e-8, "thrusters.max_thrust_n", "exceed"),
    ("noise.no_such_source", 1.0, "noise.no_such_source", "does not exist"),
    ("grs.sensors.5.com_offset_m", [0, 0, 0], "grs.sensors.5", "does not exist"),
]


@pytest.mark.parametrize(("key", "value", "parameter", "problem"), BAD_OVERRIDES,
                         ids=[f"{c[0]}={c[1]!r}"[:60] for c in BAD_OVERRIDES])
def test_bad_values_name_the_parameter(key, value, parameter, problem):
    with pytest.raises(ConfigError) as caught:
        load_config("type1", overrides={key: value})
    error = caught.value
    assert isinstance(error, ValueError)
    assert error.parameter == parameter
    assert str(error).startswith(f"{parameter}: ")
    assert problem in str(error)


def test_example_message_of_the_brief():
    bad = [[1100, 0, 0], [0, -1400, 0], [0, 0, 2400]]
    with pytest.raises(ConfigError, match=r"^spacecraft\.inertia_kg_m2: not symmetric positive definite"):
        load_config("type1", overrides={"spacecraft.inertia_kg_m2": bad})


def test_unknown_layout():
    with pytest.raises(ConfigError) as caught:
        load_config("type3")
    assert caught.value.parameter == "layout"
    assert "type3" in str(caught.value) and "type1" in str(caught.value)


def test_missing_and_unknown_keys_in_a_file(tmp_path):
    plain = load_config("type1").to_dict()
    del plain["spacecraft"]["mass_kg"]
    path = tmp_path / "missing.yaml"
    path.write_text(yaml.safe_dump(plain))
    with pytest.raises(ConfigError, match=r"^spacecraft\.mass_kg: missing key$"):
        load_config(path)

    plain = load_config("type1").to_dict()
    del plain["noise"]["srp"]
    with pytest.raises(ConfigError, match=r"^noise\.srp: missing key$"):
        load_config(plain)

    plain = load_config("type1").to_dict()
    plain["noise"]["lfs_rotational"]["asd_typo"] = 1.0
    with pytest.raises(ConfigError, match=r"^noise\.lfs_rotational\.asd_typo: unknown key$"):
        load_config(plain)

    path = tmp_path / "broken.yaml"
    path.write_text("spacecraft: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(path)
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "absent.yaml")
