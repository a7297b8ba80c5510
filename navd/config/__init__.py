"""Configuration: one TOML file, every key with its unit in its name, SI inside.

:mod:`navd.config.load` reads the file and ``--set`` overrides and builds typed sections;
:mod:`navd.config.estimator` is the estimator's view, :mod:`navd.config.daemon` the daemon's.
"""

from navd.config.estimator import (
    EstimatorConfig,
    FilterSection,
    GnssSection,
    HeadingSection,
    ImuSection,
    InitSection,
    MctlsSection,
)
from navd.config.load import ConfigError, apply_overrides, load_config, parse_override

__all__ = [
    "ConfigError",
    "EstimatorConfig",
    "FilterSection",
    "GnssSection",
    "HeadingSection",
    "ImuSection",
    "InitSection",
    "MctlsSection",
    "apply_overrides",
    "load_config",
    "parse_override",
]
