"""grassd.daemon.core.config.schema: one validator for config, bundle manifests and capture.toml."""

from __future__ import annotations

import re
from dataclasses import dataclass

import pytest

from grassd.calib.ccm import CCM_FORMS
from grassd.daemon.core.config import schema
from grassd.daemon.core.config.settings import (
    CCM_CHOICES,
    CalibrationConfig,
    default_config_text,
    parse_config,
)
from grassd.daemon.core.errors import ConfigError, ManifestError
from grassd.sim.scene import MAX_REPLICATES


@dataclass(frozen=True)
class Pump:
    name: str
    rate_l_min: float = 2.5
    on: bool = True


def test_schema_takes_each_default_from_the_dataclass():
    fields = schema.schema(Pump, name=schema.Field(str), rate_l_min=schema.Field(float),
                           on=schema.Field(bool), note=schema.Field(str, ""))
    assert fields["name"].default is schema.MISSING
    assert (fields["rate_l_min"].default, fields["on"].default, fields["note"].default) == (
        2.5, True, "")
    ctx = schema.Context('name = "p1"\n', "pump.toml")
    assert schema.table(ctx, (), {"name": "p1"}, fields) == {
        "name": "p1", "rate_l_min": 2.5, "on": True, "note": ""}


def test_a_default_written_on_both_sides_is_refused():
    with pytest.raises(TypeError, match="Pump.rate_l_min is written twice"):
        schema.schema(Pump, rate_l_min=schema.Field(float, 3.0))


def test_errors_name_file_line_and_key_in_the_documents_error_type():
    text = 'name = "p1"\n\n[pipe]\nlength_m = "long"\n'
    ctx = schema.Context(text, "pump.toml", error=ManifestError)
    with pytest.raises(ManifestError) as info:
        schema.table(ctx, ("pipe",), {"length_m": "long"}, {"length_m": schema.Field(float)})
    assert str(info.value) == ("pump.toml:4: pipe.length_m: must be a finite number, "
                               "got str 'long'")
    assert (info.value.key, info.value.line) == ("pipe.length_m", 4)
    json_ctx = schema.Context("", None, error=ManifestError)  # JSON: the key, no file line
    with pytest.raises(ManifestError, match="^length_m: unknown key"):
        schema.table(json_ctx, (), {"length_m": 1}, {"name": schema.Field(str)})


def test_the_replicate_limit_is_the_renderers():
    text = default_config_text()
    assert parse_config(text).calibration.replicates == CalibrationConfig.replicates
    top = re.sub(r"(?m)^replicates = \d+", f"replicates = {MAX_REPLICATES}", text)
    assert top != text
    assert parse_config(top).calibration.replicates == MAX_REPLICATES
    with pytest.raises(ConfigError, match=f"between 2 and {MAX_REPLICATES}, got "
                                          f"{MAX_REPLICATES + 1}"):
        parse_config(top.replace(f"replicates = {MAX_REPLICATES}",
                                 f"replicates = {MAX_REPLICATES + 1}", 1))


def test_calibration_ccm_offers_auto_and_every_form_calib_fits():
    """``[calibration] ccm`` names its choices without importing numpy; they stay the forms
    :mod:`grassd.calib.ccm` fits."""
    assert CCM_CHOICES == ("auto", *CCM_FORMS)
