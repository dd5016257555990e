"""The documented parameter file: complete, loadable, defaults consistent, bad keys named."""

import re

import pytest

from taiji2_estimator_pkg.core.instrument import InstrumentModel
from taiji2_estimator_pkg.core.parameters import (
    DEFAULTS,
    com_offset_options,
    default_parameters_file,
    load_parameters,
    paper_com_offset_options,
    paper_scale_factor_options,
    scale_factor_options,
)


def test_every_parameter_is_documented_with_its_default():
    path = default_parameters_file()
    assert path is not None
    text = path.read_text(encoding="utf-8")
    for node, defaults in DEFAULTS.items():
        params = load_parameters(node, path)
        assert params == defaults  # the file states the defaults
        for key in defaults:
            leaf = key.split(".")[-1]
            lines = [line for line in text.splitlines() if re.match(rf"\s*{leaf}:", line)]
            assert lines and all("#" in line for line in lines), f"{node}.{key} undocumented"


def test_options_built_from_parameters():
    sf = load_parameters("scale_factor_estimator", overrides={"gate_probability": 0.0, "paper.window": 1001})
    assert scale_factor_options(sf).gate_probability is None
    assert paper_scale_factor_options(sf).window == 1001
    co = load_parameters("com_offset_estimator", overrides={"detrend": "constant", "validation.saturation_v": 0})
    assert com_offset_options(co).detrend == "constant"
    assert com_offset_options(co).validation.saturation_v is None
    assert paper_com_offset_options(co).window == 2001


def test_unknown_key_and_node_named():
    with pytest.raises(ValueError, match=r"scale_factor_estimator\.gate_probabilty: unknown parameter"):
        load_parameters("scale_factor_estimator", overrides={"gate_probabilty": 1e-3})
    with pytest.raises(ValueError, match="node"):
        load_parameters("nope")


def test_instrument_from_layout_without_simulator_mapping():
    layout = {"sample_rate_hz": 10.0, "grs": {"alpha_deg": 60.0, "tm_side_m": 0.046, "electrode_lever_arm_m": 0.0115},
              "noise": {"thruster_force": {"enabled": False, "asd_n_rthz": 1e-7}}}
    instrument = InstrumentModel.from_layout(layout)
    assert instrument.noise.enabled["thruster_force"] is False
    assert instrument.linear_ratio_m == pytest.approx(0.046**2 / (6 * 0.0115))
    assert instrument.nominal_scale_factors[1][2] == pytest.approx(7.365e-8)
