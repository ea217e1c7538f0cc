"""The error every configuration check raises (schema validation, cross-field checks, experiment lookup)."""


class ConfigError(ValueError):
    """A configuration value is missing or not allowed; the message names the key."""
