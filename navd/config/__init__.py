"""Configuration: one TOML file, every key with its unit in its name, SI inside.

One naming rule for every section: the TOML key is ``<name>_<unit>`` (bare ``<name>`` when
unitless), the Python attribute is ``<name>`` and holds the SI value.  One builder:
:func:`build_section` (:mod:`navd.config.load`, which also reads the file and ``--set``
overrides).  The sections: :mod:`navd.config.estimator` (the estimator's),
:mod:`navd.config.aiding` (``[polarization]``, ``[dov]``, and :class:`NavConfig`, all the
estimator is built from), :mod:`navd.config.daemon` (``navd run``'s own sections).
"""

from navd.config.aiding import DovSection, NavConfig, PolarizationSection
from navd.config.estimator import (
    EstimatorConfig,
    FilterSection,
    GnssSection,
    HeadingSection,
    ImuSection,
    InitSection,
    MctlsSection,
    YawBankSection,
)
from navd.config.load import (
    ConfigError,
    apply_overrides,
    build_section,
    load_config,
    parse_override,
    set_override,
    setting,
    toml_keys,
)

__all__ = [
    "ConfigError",
    "DovSection",
    "EstimatorConfig",
    "FilterSection",
    "GnssSection",
    "HeadingSection",
    "ImuSection",
    "InitSection",
    "MctlsSection",
    "NavConfig",
    "PolarizationSection",
    "YawBankSection",
    "apply_overrides",
    "build_section",
    "load_config",
    "parse_override",
    "set_override",
    "setting",
    "toml_keys",
]
